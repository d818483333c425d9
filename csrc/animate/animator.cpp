#include "animate/animator.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "animate/visibility.h"
#include "common/constants.h"
#include "common/device_graph.h"
#include "common/stage_timer.h"
#include "common/tensor_description.h"

namespace sfgs::animate {
namespace {

void check_host_pose(const body::SmplxPose& pose) {
  for (const body::SmplxPose::Field& f : body::SmplxPose::fields()) {
    const at::Tensor& t = pose.*(f.member);
    TORCH_CHECK(!t.defined() || (t.is_cpu() && at::isFloatingType(t.scalar_type())), "Animator: pose.", f.name,
                " must be a floating tensor on the CPU (it is checked there and uploaded with the frame), got ",
                describe(t));
  }
  const std::string non_finite = pose.non_finite();
  TORCH_CHECK(non_finite.empty(), "Animator: pose.", non_finite);
}

}  // namespace

Animator::Animator(model::Avatar avatar, const Camera& camera, const at::Tensor& background, AnimatorOptions options)
    : avatar_(std::move(avatar)), camera_(camera), options_(options), device_(avatar_->part_labels().device()) {
  const std::string problem = camera_problem(camera_);
  TORCH_CHECK(problem.empty(), "Animator: ", problem);
  TORCH_CHECK(options_.budget_slack >= 1 && std::isfinite(options_.budget_slack),
              "Animator: budget_slack must be a finite number >= 1, got ", options_.budget_slack);
  TORCH_CHECK(background.defined() && background.dim() == 1 && background.size(0) == 3 &&
                  at::isFloatingType(background.scalar_type()),
              "Animator: background must be a floating (3) tensor, got ", describe(background));
  TORCH_CHECK(std::isfinite(options_.back_facing_cosine), "Animator: back_facing_cosine must be finite, got ",
              options_.back_facing_cosine);
  background_ = background.to(device_, at::kFloat).contiguous();
  camera_centre_ = at::empty({3}, at::TensorOptions(device_).dtype(at::kFloat));
  set_camera(camera_);
  avatar_->eval();
  avatar_->cache_static_features();
  if (device_.is_cuda()) budget_ = std::make_unique<GrowingBudget>(device_, options_.budget_slack, "Animator");
}

Animator::~Animator() = default;

void Animator::set_camera(const Camera& camera) {
  const std::string problem = camera_problem(camera);
  TORCH_CHECK(problem.empty(), "Animator: ", problem);
  camera_ = camera;
  const std::array<double, 3> centre = camera_centre(camera_);
  camera_centre_.copy_(at::tensor({centre[0], centre[1], centre[2]}, at::kDouble));
  graph_.reset();  // the camera is part of the recorded launches
}

at::Tensor Animator::splat(const model::AvatarOutput& out) {
  const StageScope stage("render");
  Gaussians gaussians = model::to_gaussians(out);
  gaussians.opacities = cull_back_facing(gaussians.opacities, out.means, out.posed_normals, camera_centre_,
                                         options_.back_facing_cosine);
  return sfgs::render(gaussians, background_, camera_, options_.render).image;
}

at::Tensor Animator::render(const body::SmplxPose& pose, model::FrameTime time) {
  check_host_pose(pose);
  ++stats_.frames;
  const bool graphs = options_.use_graph && device_.is_cuda() && device_graphs_available();
  return graphs && !time ? render_with_graph(pose) : render_eagerly(pose, time);
}

at::Tensor Animator::render_eagerly(const body::SmplxPose& pose, model::FrameTime time) {
  at::NoGradGuard no_grad;
  return splat(avatar_->forward_trusted_pose(pose, time));
}

void Animator::stage_pose(const body::SmplxPose& pose) {
  // A graph holds one layout of pose fields.
  const std::string layout = pose.layout();
  const at::Tensor packed = pose.packed();
  if (layout != layout_) {
    // A new layout: new device fields (views of one buffer, each with the caller's shape) and a new graph.
    graph_.reset();
    layout_ = layout;
    staged_values_ = at::empty({packed.size(0)}, at::TensorOptions(device_).dtype(at::kFloat));
    staged_pose_ = pose.views_of(staged_values_);
  }
  staged_values_.copy_(packed);  // one upload per frame
}

void Animator::capture() {
  const auto frame = [this] {
    at::NoGradGuard no_grad;
    const ScopedBinningBudget budget(budget_->budget(avatar_->gaussian_count()));
    image_ = splat(avatar_->forward_trusted_pose(staged_pose_, std::nullopt));
  };
  if (!budget_->measured()) {
    // The first frame of this avatar: eager passes (which also make every lazy one-time allocation outside the
    // graph) find a budget that fits, starting from a guess and growing it.
    for (;;) {
      frame();
      const BinningCounts counts = budget_->read();
      const bool fitted = budget_->fits(counts);
      budget_->grow(counts);
      if (fitted) break;
    }
  }
  graph_ = capture_device_graph(frame);
  ++stats_.captures;
  stats_.budget = budget_->intersections();
}

at::Tensor Animator::render_with_graph(const body::SmplxPose& pose) {
  stage_pose(pose);
  for (;;) {
    if (!graph_) capture();
    graph_->replay();
    const BinningCounts counts = budget_->read();
    stats_.intersections = counts.intersections;
    if (budget_->fits(counts)) break;
    // The pass was emptied on the device: grow the budget, record again, and replay the same frame.
    ++stats_.budget_overflows;
    budget_->grow(counts);
    graph_.reset();
  }
  ++stats_.graph_frames;
  return image_;
}

}  // namespace sfgs::animate
