#pragma once
// Several frames of one avatar in one call: B poses (with their times) seen by B cameras of one image size, rendered
// by up to kBatchLanes Animators at once. On CUDA each lane replays its graph on a stream of its own (a batch of one
// frame stays on the caller's stream), and the host queues a lane's next frame as soon as that lane's last one is
// done, so the GPU runs several frames side by side; on the CPU one lane renders them in turn. Results are stacked on
// a first dimension of B and belong to the caller (no later frame overwrites them); the caller's stream waits for
// them, and the lanes wait for the caller's earlier work (a parameter update, say) before they read the avatar.
#include <memory>
#include <vector>

#include <ATen/core/Tensor.h>

#include "animate/animator.h"
#include "animate/constants.h"

namespace sfgs::animate {

struct BatchFrame {
  Camera camera;
  body::SmplxPose pose;  // on the CPU, as Animator::render takes it
  model::FrameTime time;
};

class BatchAnimator {
 public:
  BatchAnimator(model::Avatar avatar, const at::Tensor& background, AnimatorOptions options = {},
                int64_t lanes = kBatchLanes);
  ~BatchAnimator();
  BatchAnimator(const BatchAnimator&) = delete;
  BatchAnimator& operator=(const BatchAnimator&) = delete;

  // image (B, H, W, C), alpha and depth (B, H, W), radii (B, N, 2), visible (B, N). Every camera must have the
  // first one's image size.
  RenderResult render(const std::vector<BatchFrame>& frames);
  // Later frames get this background (3).
  void set_background(const at::Tensor& background);
  // Summed over the lanes.
  AnimatorStats stats() const;
  int64_t lane_count() const { return int64_t(lanes_.size()); }

 private:
  struct Lane;
  Lane& lane(size_t index, const Camera& camera);

  model::Avatar avatar_;
  at::Tensor background_;
  AnimatorOptions options_;
  int64_t max_lanes_;
  std::vector<std::unique_ptr<Lane>> lanes_;
};

}  // namespace sfgs::animate
