#pragma once
// The whole-body keypoints of a posed avatar and their reprojection error against a frame's detections: what holds
// test-time pose fitting (train/pose_fit.h) and pose refinement (train/pose_refinement.h) to the body a detector saw,
// where the image alone trades the body's placement against its joints (docs/training.md, "Imperfect fits"). The
// keypoints are defined on the body model (body/wholebody_keypoints.h), by the definition `sfgs synth` projects and
// `sfgs fit` fits to, and read from the avatar's own posed model vertices and joints, so they move with its pose
// exactly as its Gaussians do.
#include <string>

#include <ATen/core/Tensor.h>

#include "body/wholebody_keypoints.h"
#include "fit/fit_losses.h"
#include "model/avatar.h"
#include "ops/splat/splat.h"
#include "fit/constants.h"

namespace sfgs::train {

// The keypoint map of the body model a run was built from (its body.smplx; empty: the built-in procedural body).
body::WholeBodyKeypointMap body_keypoint_map(const std::string& smplx_path);

// One frame's detections as the reprojection term reads them, made once per frame on the detections' device (a
// step then uploads nothing).
struct FrameKeypoints {
  fit::KeypointObservations observed;  // pixels undefined: the frame has no detections
  at::Tensor world_to_camera;          // (4, 4) of the frame's render camera
  at::Tensor weights;                  // (133) per keypoint (fit::whole_body_keypoint_weights)
  bool defined() const { return observed.pixels.defined(); }
};
// detections (133, 3) [x, y, score] in the pixels of `camera`'s image, any floating dtype (taken as float32). A
// frame whose points all score below kFitMinKeypointScore adds nothing.
FrameKeypoints frame_keypoints(const at::Tensor& detections, const Camera& camera);

// (133, 3) the keypoints of `out` (a frame `avatar` posed) in camera coordinates (metres, OpenCV axes) for a
// (4, 4) world_to_camera on the avatar's device. `map` must be built for the avatar's body model and lie on its
// device in its dtype.
at::Tensor avatar_camera_keypoints(const body::WholeBodyKeypointMap& map, const model::Avatar& avatar,
                                   const model::AvatarOutput& out, const at::Tensor& world_to_camera);

// The robust, confidence-weighted reprojection error (fit::reprojection_loss over every keypoint group) of `out`'s
// keypoints against the frame's detections (which must be defined); a 0-dim tensor with a gradient to the pose.
at::Tensor keypoint_reprojection_loss(const body::WholeBodyKeypointMap& map, const model::Avatar& avatar,
                                      const model::AvatarOutput& out, const FrameKeypoints& keypoints);

}  // namespace sfgs::train
