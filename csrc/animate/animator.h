#pragma once
// Real-time animation of a trained avatar: pose in, image out, as fast as the GPU allows. Everything that depends
// on neither pose nor time is baked once (the avatar's static-feature cache); the per-frame work (pose and hand
// networks, body, structure offset, fused skinning, normals, shading, splatting) is recorded once as a CUDA graph
// and each frame is one replay: one small upload of the pose, one launch, and one wait for the image at the end.
// The splatting's intersection buffers are sized from a budget (splat.h, BinningBudget) that the Animator grows and
// captures again whenever a frame reports it was exceeded, so every returned image is complete. On the CPU, with a
// frame time (replay of a training frame), or with use_graph off, frames run eagerly. docs/performance.md.
#include <array>
#include <memory>
#include <string>

#include <ATen/core/Tensor.h>

#include "body/smplx_pose.h"
#include "common/constants.h"
#include "model/avatar.h"
#include "splat/growing_budget.h"
#include "splat/splat.h"

namespace sfgs {
class DeviceGraph;
}  // namespace sfgs

namespace sfgs::animate {

struct AnimatorOptions {
  bool use_graph = true;  // CUDA: one graph replay per frame (false: every frame runs eagerly)
  // Headroom of the splatting budget over the counts of the frame it was taken from (>= 1): a new pose or camera
  // may touch more tiles; a frame beyond the budget is recorded and replayed again, once.
  double budget_slack = kGraphBudgetSlack;
  // Gaussians facing away from the camera by more than this cosine are not splatted (animate/visibility.h);
  // >= 1 (the default) splats every Gaussian, as the exact render does; kAnimatorFastBackFacingCosine trades
  // accuracy for speed (docs/performance.md).
  double back_facing_cosine = kAnimatorBackFacingCosine;
  RenderOptions render;
};

struct AnimatorStats {
  int64_t frames = 0;
  int64_t graph_frames = 0;      // frames that were one graph replay
  int64_t captures = 0;          // graphs recorded (first frame, new pose layout, camera, or budget)
  int64_t budget_overflows = 0;  // replays that reported a larger pass than their budget, and ran again
  int64_t intersections = 0;     // of the latest graph frame
  int64_t budget = 0;            // the intersection budget of the current graph
};

class Animator {
 public:
  // The avatar is switched to eval mode and keeps its static-feature cache; background (C) matches its colours.
  Animator(model::Avatar avatar, const Camera& camera, const at::Tensor& background, AnimatorOptions options = {});
  ~Animator();
  Animator(const Animator&) = delete;
  Animator& operator=(const Animator&) = delete;

  // One frame (H, W, C) on the avatar's device: a new motion's pose (time none), or a training frame's replay
  // (time in [-1, 1], run eagerly). The pose's tensors must be on the CPU, where they are checked; the image is
  // overwritten by the next graph frame (clone it to keep it).
  at::Tensor render(const body::SmplxPose& pose, model::FrameTime time = std::nullopt);
  // Later frames are seen by `camera` (the next graph frame captures again).
  void set_camera(const Camera& camera);

  const AnimatorStats& stats() const { return stats_; }
  at::Device device() const { return device_; }

 private:
  at::Tensor render_eagerly(const body::SmplxPose& pose, model::FrameTime time);
  // The frame's image from the posed avatar, back-facing Gaussians culled.
  at::Tensor splat(const model::AvatarOutput& out);
  at::Tensor render_with_graph(const body::SmplxPose& pose);
  void stage_pose(const body::SmplxPose& pose);
  void capture();

  model::Avatar avatar_;
  Camera camera_;
  at::Tensor background_;
  at::Tensor camera_centre_;  // (3) on the device, updated in place (graphs read it)
  AnimatorOptions options_;
  at::Device device_;
  AnimatorStats stats_;
  // Graph state: the pose's device copy (one flat buffer and the fields as its views), the layout it was made for,
  // the splatting budget (CUDA only), and the graph's output.
  std::string layout_;
  at::Tensor staged_values_;
  body::SmplxPose staged_pose_;
  std::unique_ptr<GrowingBudget> budget_;
  at::Tensor image_;
  std::unique_ptr<DeviceGraph> graph_;
};

}  // namespace sfgs::animate
