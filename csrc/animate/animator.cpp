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
  if (device_.is_cuda()) counts_ = at::zeros({BinningBudget::kCounts}, at::TensorOptions(device_).dtype(at::kLong));
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

std::array<int64_t, 3> Animator::read_counts() {
  const at::Tensor host = counts_.cpu();  // waits for the frame
  const int64_t* v = host.data_ptr<int64_t>();
  return {v[0], v[1], v[2]};
}

void Animator::grow_budget(const std::array<int64_t, 3>& counts) {
  TORCH_CHECK(counts[2] == 0, "Animator: ", counts[2], " opacities of the posed avatar are not finite or outside [0, 1]");
  intersection_budget_ = std::max<int64_t>(1, std::llround(double(counts[0]) * options_.budget_slack));
  tile_budget_ = std::max<int64_t>(1, std::llround(double(counts[1]) * options_.budget_slack));
}

void Animator::capture() {
  const auto frame = [this] {
    at::NoGradGuard no_grad;
    const ScopedBinningBudget budget(BinningBudget{intersection_budget_, tile_budget_, counts_});
    image_ = splat(avatar_->forward_trusted_pose(staged_pose_, std::nullopt));
  };
  if (intersection_budget_ == 0) {
    // The first frame of this avatar: eager passes (which also make every lazy one-time allocation outside the
    // graph) find a budget that fits, starting from a guess and growing it.
    intersection_budget_ = std::max<int64_t>(1, avatar_->gaussian_count() * kGraphInitialIntersectionsPerGaussian);
    tile_budget_ = intersection_budget_;
    for (;;) {
      frame();
      const std::array<int64_t, 3> counts = read_counts();
      const bool fitted = counts[0] <= intersection_budget_;
      grow_budget(counts);
      if (fitted) break;
    }
  }
  graph_ = capture_device_graph(frame);
  ++stats_.captures;
  stats_.budget = intersection_budget_;
}

at::Tensor Animator::render_with_graph(const body::SmplxPose& pose) {
  stage_pose(pose);
  for (;;) {
    if (!graph_) capture();
    graph_->replay();
    const std::array<int64_t, 3> counts = read_counts();
    stats_.intersections = counts[0];
    if (counts[0] <= intersection_budget_ && counts[1] <= tile_budget_ && counts[2] == 0) break;
    // The pass was emptied on the device: grow the budget, record again, and replay the same frame.
    ++stats_.budget_overflows;
    grow_budget(counts);
    graph_.reset();
  }
  ++stats_.graph_frames;
  return image_;
}

}  // namespace sfgs::animate
