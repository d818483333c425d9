#pragma once
// Real-time animation of a trained avatar: pose, time and camera in, image out, as fast as the GPU allows. Everything
// that depends on neither pose nor time is baked once (the avatar's static-feature cache); the per-frame work (pose
// and hand networks, body, the time-dependent attributes of a replayed frame, structure offset, fused skinning,
// normals, shading, splatting) is recorded once as a CUDA graph and each frame is one replay: two small uploads (the
// pose; the camera's placement and the time), one launch, and one wait for the image at the end.
//
// The camera's placement (world_to_camera) is an input of the recorded frame, not part of it: the posed Gaussians
// are moved into the camera's frame on the device (ops/splat/camera_frame.h, as the training step does) and splatted by
// a camera at the origin with the same intrinsics,
// so a moving camera (every frame of a video or a dataset) replays the same graph. A new intrinsic matrix, image
// size, pose layout, or a change between replayed (timed) and new-motion frames records again.
//
// The splatting's intersection buffers are sized from a budget (splat.h, BinningBudget) that the Animator grows and
// captures again whenever a frame reports it was exceeded, so every returned image is complete. On the CPU, or with
// use_graph off, the same frame runs eagerly. docs/performance.md.
//
// An avatar with a sampling record (model/sampling_filter.h) seen more finely than its training views saw it (closer,
// or at a higher resolution) has its Gaussians widened to the training's blur, so it shows no holes or dots; at the
// training's sampling nothing changes.
#include <array>
#include <memory>
#include <string>

#include <ATen/core/Tensor.h>

#include "body/smplx_pose.h"
#include "animate/constants.h"
#include "ops/splat/constants.h"
#include "model/avatar.h"
#include "ops/splat/camera_frame.h"
#include "ops/splat/growing_budget.h"
#include "ops/splat/splat.h"

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
  int64_t captures = 0;          // graphs recorded (first frame, new pose layout, intrinsics, timing, or budget)
  int64_t budget_overflows = 0;  // replays that reported a larger pass than their budget, and ran again
  int64_t intersections = 0;     // of the latest graph frame
  int64_t budget = 0;            // the intersection budget of the current graph
};

class Animator {
 public:
  // The avatar is switched to eval mode and keeps its static-feature cache (made here unless the avatar has one, and
  // made again when someone else clears it; a replaced cache records the graph again); background (C) matches its
  // colours.
  Animator(model::Avatar avatar, const Camera& camera, const at::Tensor& background, AnimatorOptions options = {});
  ~Animator();
  Animator(const Animator&) = delete;
  Animator& operator=(const Animator&) = delete;

  // One frame (H, W, C) on the avatar's device: a new motion's pose (time none), or a training frame's replay
  // (time in [-1, 1]). The pose's tensors must be on the CPU, where they are checked; the image is overwritten by the
  // next graph frame (clone it to keep it).
  at::Tensor render(const body::SmplxPose& pose, model::FrameTime time = std::nullopt);
  // The same frame in two halves, so that the host can queue the frames of several Animators (each on a stream of its
  // own, animate/batch_animator.h) before it waits for any: submit() checks and stages the frame and queues it on the
  // current stream (a graph replay; an eager frame is rendered there and then), finish() waits for it, renders it
  // again should it have outgrown the splatting budget, and returns its result (overwritten by the next frame).
  // render() is submit() then finish(); a second submit() needs a finish() between.
  void submit(const body::SmplxPose& pose, model::FrameTime time = std::nullopt);
  const RenderResult& finish();
  // The whole result of the latest frame (image, alpha, depth, and per Gaussian radii and visibility), with depth in
  // the camera's frame; overwritten by the next graph frame like the image.
  const RenderResult& latest() const { return result_; }
  // Later frames are seen by `camera`. Only new intrinsics or a new image size record the next graph frame again.
  void set_camera(const Camera& camera);
  const Camera& camera() const { return camera_; }
  // Later frames get this background (3): written into the tensor the graph reads, so nothing records again.
  void set_background(const at::Tensor& background);

  const AnimatorStats& stats() const { return stats_; }
  at::Device device() const { return device_; }

 private:
  // The posed avatar's image, seen from the staged camera (back-facing Gaussians culled), into result_; with a
  // budget (a recorded frame), its buffers sized from it (splat.h).
  void splat(const model::AvatarOutput& out, const BinningBudget* budget = nullptr);
  void render_eagerly(const body::SmplxPose& pose, model::FrameTime time);
  void launch_graph_frame(const body::SmplxPose& pose, model::FrameTime time);
  void finish_graph_frame();
  void stage_pose(const body::SmplxPose& pose);
  void stage_frame(model::FrameTime time);
  void capture(bool timed);
  // Makes the avatar's static-feature cache when it has none.
  void keep_cache();

  model::Avatar avatar_;
  Camera camera_;
  Camera origin_camera_;  // camera_'s intrinsics at the origin: what splats the Gaussians moved into its frame
  at::Tensor background_;
  AnimatorOptions options_;
  at::Device device_;
  AnimatorStats stats_;
  // The frame's values on the device, one buffer uploaded per frame: the camera's placement (camera_frame.h), its
  // centre in the world (3) for the back-facing cull, and the time (0-dim); graphs read them.
  at::Tensor frame_values_, camera_centre_, time_;
  CameraFrame camera_frame_;
  // The avatar's sampling record on the device (model/sampling_filter.h), undefined without one: a frame that
  // samples a Gaussian more finely than training did widens it to the training's blur.
  at::Tensor sampling_record_;
  // Graph state: the pose's device copy (one flat buffer and the fields as its views), the key the graph was
  // recorded for (pose layout, timing, intrinsics), the splatting budget (CUDA only), and the graph's result.
  std::string graph_key_;
  int64_t cache_generation_ = -1;  // of the avatar's cache the graph reads
  std::string layout_;
  at::Tensor staged_values_;
  body::SmplxPose staged_pose_;
  std::unique_ptr<GrowingBudget> budget_;
  RenderResult result_;
  std::unique_ptr<DeviceGraph> graph_;
  // The submitted frame not yet finished: none, one already rendered (eagerly), or a queued replay.
  enum class Pending { kNone, kRendered, kReplay } pending_ = Pending::kNone;
  bool pending_timed_ = false;
};

}  // namespace sfgs::animate
