#include "animate/animator.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "animate/visibility.h"
#include "common/device_graph.h"
#include "common/stage_timer.h"
#include "common/tensor_description.h"
#include "model/sampling_filter.h"

namespace sfgs::animate {
namespace {

// The frame values' layout in Animator::frame_values_: the camera's placement, its centre, the time.
constexpr int64_t kCentreValues = 3, kFrameValues = kCameraFrameValues + kCentreValues + 1;

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

// What a graph holds of a camera: everything but its placement.
std::string intrinsics_key(const Camera& c) {
  char key[256];
  std::snprintf(key, sizeof key, "%.17g %.17g %.17g %.17g %lld %lld %.17g %.17g", c.fx, c.fy, c.cx, c.cy,
                static_cast<long long>(c.width), static_cast<long long>(c.height), c.near_plane, c.far_plane);
  return key;
}

}  // namespace

Animator::Animator(model::Avatar avatar, const Camera& camera, const at::Tensor& background, AnimatorOptions options)
    : avatar_(std::move(avatar)), camera_(camera), options_(options), device_(avatar_->part_labels().device()) {
  TORCH_CHECK(options_.budget_slack >= 1 && std::isfinite(options_.budget_slack),
              "Animator: budget_slack must be a finite number >= 1, got ", options_.budget_slack);
  TORCH_CHECK(std::isfinite(options_.back_facing_cosine), "Animator: back_facing_cosine must be finite, got ",
              options_.back_facing_cosine);
  background_ = at::empty({3}, at::TensorOptions(device_).dtype(at::kFloat));
  set_background(background);
  frame_values_ = at::zeros({kFrameValues}, at::TensorOptions(device_).dtype(at::kFloat));
  camera_frame_ = CameraFrame(frame_values_.narrow(0, 0, kCameraFrameValues));
  camera_centre_ = frame_values_.narrow(0, kCameraFrameValues, kCentreValues);
  time_ = frame_values_.select(0, kCameraFrameValues + kCentreValues);
  set_camera(camera);
  avatar_->eval();
  keep_cache();
  if (avatar_->sampling_record().defined()) sampling_record_ = avatar_->sampling_record().to(device_);
  if (device_.is_cuda()) budget_ = std::make_unique<GrowingBudget>(device_, options_.budget_slack, "Animator");
}

Animator::~Animator() = default;

void Animator::keep_cache() {
  if (!avatar_->has_cache()) avatar_->cache_static_features();
}

void Animator::set_camera(const Camera& camera) {
  const std::string problem = camera_problem(camera);
  TORCH_CHECK(problem.empty(), "Animator: ", problem);
  camera_ = camera;
  origin_camera_ = camera_at_origin_of(camera);
}

void Animator::set_background(const at::Tensor& background) {
  TORCH_CHECK(background.defined() && background.dim() == 1 && background.size(0) == 3 &&
                  at::isFloatingType(background.scalar_type()),
              "Animator: background must be a floating (3) tensor, got ", describe(background));
  const at::Tensor values = background.detach().to(at::kCPU, at::kFloat);
  TORCH_CHECK(values.isfinite().all().item<bool>(), "Animator: background must be finite, got ", values);
  background_.copy_(values);
}

void Animator::stage_frame(model::FrameTime time) {
  TORCH_CHECK(!time || (std::isfinite(*time) && *time >= -1.0 && *time <= 1.0),
              "Animator: time must be normalised to [-1, 1] (once per sequence), got ", *time);
  std::vector<float> values(kFrameValues);
  write_camera_frame(camera_, values.data());
  const std::array<double, 3> centre = camera_centre(camera_);
  std::copy(centre.begin(), centre.end(), values.begin() + kCameraFrameValues);
  values.back() = static_cast<float>(time.value_or(0.0));
  frame_values_.copy_(at::tensor(values, at::kFloat));  // one upload per frame
}

void Animator::splat(const model::AvatarOutput& out, const BinningBudget* budget) {
  const StageScope stage("render");
  Gaussians gaussians = model::to_gaussians(out);
  gaussians.opacities =
      cull_back_facing(gaussians.opacities, out.means, out.posed_normals, camera_centre_, options_.back_facing_cosine);
  gaussians.means = camera_frame_.points(gaussians.means);
  gaussians.covariances = camera_frame_.covariances(gaussians.covariances);
  if (sampling_record_.defined())
    gaussians.covariances =
        model::sampling_filtered(gaussians.covariances, gaussians.means, origin_camera_, sampling_record_);
  RenderOptions render_options = options_.render;
  render_options.budget = budget;
  result_ = sfgs::render(gaussians, background_, origin_camera_, render_options);
}

at::Tensor Animator::render(const body::SmplxPose& pose, model::FrameTime time) {
  submit(pose, time);
  return finish().image;
}

void Animator::submit(const body::SmplxPose& pose, model::FrameTime time) {
  TORCH_CHECK(pending_ == Pending::kNone, "Animator: submit() again before finish() of the frame submitted before");
  check_host_pose(pose);
  ++stats_.frames;
  stage_frame(time);
  if (options_.use_graph && device_.is_cuda() && device_graphs_available()) {
    launch_graph_frame(pose, time);
    pending_ = Pending::kReplay;
  } else {
    render_eagerly(pose, time);
    pending_ = Pending::kRendered;
  }
}

const RenderResult& Animator::finish() {
  TORCH_CHECK(pending_ != Pending::kNone, "Animator: finish() without a submitted frame");
  const Pending pending = pending_;
  pending_ = Pending::kNone;  // a frame that fails below is dropped: the next submit() starts clean
  if (pending == Pending::kReplay) finish_graph_frame();
  return result_;
}

void Animator::render_eagerly(const body::SmplxPose& pose, model::FrameTime time) {
  at::NoGradGuard no_grad;
  keep_cache();
  splat(avatar_->forward_trusted_pose(pose, time));
}

void Animator::stage_pose(const body::SmplxPose& pose) {
  // A graph holds one layout of pose fields.
  const std::string layout = pose.layout();
  const at::Tensor packed = pose.packed();
  if (layout != layout_) {
    // A new layout: new device fields (views of one buffer, each with the caller's shape), read by a new graph.
    layout_ = layout;
    staged_values_ = at::empty({packed.size(0)}, at::TensorOptions(device_).dtype(at::kFloat));
    staged_pose_ = pose.views_of(staged_values_);
  }
  staged_values_.copy_(packed);  // one upload per frame
}

void Animator::capture(bool timed) {
  keep_cache();
  cache_generation_ = avatar_->cache_generation();
  const auto frame = [this, timed] {
    at::NoGradGuard no_grad;
    const BinningBudget budget = budget_->budget(avatar_->gaussian_count());
    // The time as the device tensor the replays write (the cache keeps only host times' attributes).
    splat(avatar_->forward_trusted_pose(staged_pose_, timed ? time_ : at::Tensor()), &budget);
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

void Animator::launch_graph_frame(const body::SmplxPose& pose, model::FrameTime time) {
  stage_pose(pose);
  const std::string key = std::string(time ? "timed " : "new ") + layout_ + " " + intrinsics_key(camera_);
  if (key != graph_key_ || avatar_->cache_generation() != cache_generation_) {
    graph_.reset();
    graph_key_ = key;
  }
  pending_timed_ = time.has_value();
  if (!graph_) capture(pending_timed_);
  graph_->replay();
}

void Animator::finish_graph_frame() {
  for (;;) {
    const BinningCounts counts = budget_->read();
    stats_.intersections = counts.intersections;
    if (budget_->fits(counts)) break;
    // The pass was emptied on the device: grow the budget, record again, and replay the same frame (its pose and
    // values are still staged).
    ++stats_.budget_overflows;
    budget_->grow(counts);
    graph_.reset();
    capture(pending_timed_);
    graph_->replay();
  }
  ++stats_.graph_frames;
}

}  // namespace sfgs::animate
