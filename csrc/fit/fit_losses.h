#pragma once
// The terms `sfgs fit` minimises (docs/fitting.md, "Objective"): a robust, score-weighted reprojection of the 133
// whole-body keypoints, pose, hand, shape and expression priors, temporal smoothness of the posed body, and a
// silhouette term where person masks exist. All batched over the frames, differentiable, on any device.
#include <ATen/core/Tensor.h>

#include "body/wholebody_keypoints.h"
#include "fit/constants.h"

#include <cstdint>
#include <map>
#include <utility>
#include <vector>

namespace sfgs::fit {

// The detections as the losses use them.
struct KeypointObservations {
  at::Tensor pixels;       // (B, 133, 2)
  at::Tensor confidence;   // (B, 133): the score where it reaches kFitMinKeypointScore (capped at 1), else 0
  at::Tensor person_size;  // (B) pixels: the diagonal of the confident keypoints' box; residuals are divided by it
  at::Tensor intrinsics;   // (B, 4) fx, fy, cx, cy
};

// keypoints (B, 133, 3) [x, y, score] and intrinsics (B, 4), on the fit's device and dtype.
KeypointObservations observe_keypoints(const at::Tensor& keypoints, const at::Tensor& intrinsics);

// Pinhole projection of camera-space points (B, N, 3) -> (B, N, 2) pixels; depths are floored at the near plane.
at::Tensor project(const at::Tensor& points, const at::Tensor& intrinsics);

// Geman-McClure of squared residuals: sigma^2 r^2 / (sigma^2 + r^2), about r^2 for r << sigma and at most sigma^2.
at::Tensor geman_mcclure(const at::Tensor& squared, double sigma);

// (133) weights that are `weights` on each named group's keypoints and 0 elsewhere.
at::Tensor group_weights(const std::map<body::KeypointGroup, double>& weights, const at::TensorOptions& options);
// (133) the weights of a fit that sees every keypoint: the body and hands fully, the feet and the face (whose
// detections and definitions agree less well) lighter.
at::Tensor whole_body_keypoint_weights(const at::TensorOptions& options);

// Per frame (B), the sum over keypoints of weight * confidence * GM(|projection - detection| / person size).
// `keypoint_weights` (133) selects and weighs the keypoints of a stage.
at::Tensor reprojection_loss(const at::Tensor& keypoints, const KeypointObservations& observed,
                             const at::Tensor& keypoint_weights, double sigma);

// The body prior's centre and per-axis weights, (21, 3) each: a body at rest with the arms hanging rather than the
// T-pose (also where the fit starts), twists about a limb's own axis (x for the arms, y for the legs) held more
// firmly than swings, the flexion of knees and elbows free.
std::pair<at::Tensor, at::Tensor> body_prior_centre_and_weights(const at::TensorOptions& options);

// Weighted squared distance of the body joints' axis-angles from the centre, plus squared hinges on anatomically
// impossible bends (knees and elbows bending backwards or sideways), per frame (B). body_pose (B, 21, 3).
at::Tensor body_pose_prior(const at::Tensor& body_pose);

// Hand poses (B, 15, 3) relative to the mean hand: squared norm plus squared hinges on fingers bending backwards.
at::Tensor hand_pose_prior(const at::Tensor& left_hand, const at::Tensor& right_hand);

// Consecutive-frame triples (previous, current, next) of frames sorted by number whose gaps are at most twice the
// median gap: a cut or a dropped stretch breaks the chain. (T, 3) int64, possibly empty.
at::Tensor temporal_triples(const std::vector<int64_t>& frame_numbers);

// Robust acceleration of posed points (B, N, 3) over the triples (GM with sigma in metres per frame^2), mean.
at::Tensor temporal_loss(const at::Tensor& points, const at::Tensor& triples, double sigma);

}  // namespace sfgs::fit
