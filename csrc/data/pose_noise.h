#pragma once
// Fits corrupted the way monocular pose estimators err, for `sfgs synth --pose-noise`: per-joint rotation errors
// (larger on wrists and fingers), a global orientation error, translation errors across the view and along it
// (depth is what a single view measures worst), each the sum of a bias that drifts slowly over the video and
// frame-to-frame jitter, a shape error, and occasional frames whose left and right hand poses are exchanged. The
// images stay exact: only the fits written beside them change. docs/fitting.md lists the levels.
#include <ATen/core/Tensor.h>

#include <cstdint>
#include <string>

#include "body/smplx_pose.h"

namespace sfgs::data {

struct PoseNoiseLevel {
  std::string name = "none";
  double body_degrees = 0;    // RMS rotation error of each body joint but the wrists, and of the jaw and eyes
  double hand_degrees = 0;    // of each wrist and finger joint
  double root_degrees = 0;    // of the global orientation (an error about the camera's axes)
  double lateral_cm = 0;      // RMS translation error along the camera's x and y axes (each)
  double depth_cm = 0;        // along its optical axis
  double betas_sigma = 0;     // standard deviation added to every shape coefficient (once per video)
  double jitter_share = 0;    // share of each error's variance that changes every frame; the rest drifts slowly
  double drift_seconds = 1;   // correlation time of the drifting part
  double hand_swap_rate = 0;  // share of frames whose left and right hand poses are exchanged (mirrored)

  bool is_zero() const;
};

// A level by name, "none", "low", "medium" (also "default") or "high", optionally followed by overrides of its
// numbers: "medium,hands=15,depth=10,swap=0.05" (keys body, hands, root in degrees; lateral, depth in cm; betas;
// jitter, swap as shares in [0, 1]; drift in seconds). Errors name the bad part and the choices.
PoseNoiseLevel pose_noise_level(const std::string& spec);

struct NoisyFits {
  body::SmplxPose poses;     // the corrupted batch, float32 on the CPU, same layout as the input
  at::Tensor betas;          // corrupted shared shape
  at::Tensor hands_swapped;  // (B) bool: frames whose hand poses were exchanged
};

// Corrupts a batch of B frames in time order: `truth` (every field (B, ...), float32, hands as absolute axis-angle
// or relative to any mean: a swap mirrors them as given), `betas` (K), `times` (B) seconds (the drift decorrelates
// over the gaps between consecutive frames), `world_to_camera_rotations` (B, 3, 3) of each frame's camera (the
// identity for fits already in camera coordinates), so that orientation, lateral and depth errors are taken about
// the camera's axes. Deterministic for a seed; `level` all zero returns the truth unchanged.
NoisyFits corrupt_fits(const body::SmplxPose& truth, const at::Tensor& betas, const at::Tensor& times,
                       const at::Tensor& world_to_camera_rotations, const PoseNoiseLevel& level, uint64_t seed);

// The mirror image of axis-angle rotations (..., 3) through the x = 0 plane: (x, y, z) -> (x, -y, -z).
at::Tensor mirror_axis_angle(const at::Tensor& axis_angle);

}  // namespace sfgs::data
