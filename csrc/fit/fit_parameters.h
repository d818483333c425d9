#pragma once
// The unknowns of `sfgs fit`, per frame in the frame's camera coordinates, and their closed-form start: each frame's
// global orientation is the best of a ring of upright candidates (facing the camera, turned in 30-degree steps),
// with the translation that best places the rest body's torso and head keypoints on the detections for it.
#include <ATen/core/Tensor.h>

#include <cstdint>

#include "body/smplx_pose.h"
#include "body/wholebody_keypoints.h"
#include "fit/fit_losses.h"
#include "fit/keypoint_body.h"

namespace sfgs::fit {

struct FitParameters {
  at::Tensor root_start;       // (B, 3, 3) the closed-form orientation (fixed)
  at::Tensor root_correction;  // (B, 3) axis-angle on top of it: R = exp(correction) root_start
  at::Tensor translation;      // (B, 3)
  at::Tensor body_pose;        // (B, 21, 3)
  at::Tensor jaw_pose;         // (B, 3)
  at::Tensor left_hand;        // (B, 15, 3) relative to the mean hand (ExAvatar's convention)
  at::Tensor right_hand;       // (B, 15, 3)
  at::Tensor expression;       // (B, E)
  at::Tensor betas;            // (K) shared
  at::Tensor left_hand_mean;   // (15, 3) the model's mean hands (fixed)
  at::Tensor right_hand_mean;

  // (B, 55, 3, 3) local joint rotations (eyes at rest).
  at::Tensor rotations() const;
  // The frames' parameters in ExAvatar's convention (camera coordinates, hands relative to the mean), float32 CPU.
  body::SmplxPose poses() const;
};

// Rest body, candidate orientations and least-squares translations; `betas` (K) is the starting (or known) shape.
FitParameters initial_parameters(const KeypointBody& body, const body::WholeBodyKeypointMap& keypoint_map,
                                 const KeypointObservations& observed, const at::Tensor& betas,
                                 const at::Tensor& left_hand_mean, const at::Tensor& right_hand_mean,
                                 int64_t expressions);

// Parameters starting at given fits (B frames in camera coordinates, hands relative to the mean hand) and `betas`.
FitParameters parameters_from_fits(const body::SmplxPose& fits, const at::Tensor& betas,
                                   const at::Tensor& left_hand_mean, const at::Tensor& right_hand_mean,
                                   int64_t expressions, const at::TensorOptions& options);

// The (B, 133, 3) keypoints and (B, 55, 3) joints of parameters posed by `body`, in camera coordinates.
struct PosedKeypoints {
  at::Tensor keypoints;
  at::Tensor joints;
};
PosedKeypoints pose_keypoints(const KeypointBody& body, const body::WholeBodyKeypointMap& keypoint_map,
                              const FitParameters& parameters);

}  // namespace sfgs::fit
