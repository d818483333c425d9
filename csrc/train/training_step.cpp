#include "train/training_step.h"

#include <cmath>
#include <iomanip>
#include <sstream>

#include <ATen/ATen.h>

#include "common/constants.h"
#include "common/stage_timer.h"
#include "common/tensor_description.h"
#include "metrics/image_metrics.h"
#include "model/observation_prior.h"
#include "model/sampling_filter.h"

namespace sfgs::train {
namespace {

constexpr int64_t kBackgroundChannels = 3;

}  // namespace

std::string step_kind(const StepData& d) {
  const Camera& c = d.camera;
  std::ostringstream kind;
  kind << std::setprecision(17) << d.frame.size(0) << 'x' << d.frame.size(1) << " pose " << d.pose.layout() << " time "
       << d.time.has_value() << " lpips " << d.lpips << " camera " << c.fx << ',' << c.fy << ',' << c.cx << ',' << c.cy
       << ',' << c.width << ',' << c.height << ',' << c.near_plane << ',' << c.far_plane << " moves "
       << !camera_at_origin(c);
  return kind.str();
}

StepInputs::StepInputs(const StepData& like, at::Device device) : kind_(step_kind(like)) {
  const auto options = at::TensorOptions(device).dtype(at::kFloat);
  TORCH_CHECK(like.frame.dim() == 3 && like.frame.size(2) == 4 && like.frame.scalar_type() == at::kByte,
              "StepInputs: the frame must be (H, W, 4) uint8, got ", describe(like.frame));
  frame = at::empty(like.frame.sizes(), options.dtype(at::kByte));
  const at::Tensor like_pose = like.pose.packed();
  pose_values_ = like_pose.size(0);
  const bool moves = !camera_at_origin(like.camera);
  const int64_t count = pose_values_ + kBackgroundChannels + (moves ? kCameraFrameValues : 0) + (like.time ? 1 : 0);
  values_ = at::empty({count}, options);
  pose = like.pose.views_of(values_.narrow(0, 0, pose_values_));
  int64_t offset = pose_values_;
  background = values_.narrow(0, offset, kBackgroundChannels);
  offset += kBackgroundChannels;
  if (moves) {
    camera_frame = CameraFrame(values_.narrow(0, offset, kCameraFrameValues));
    offset += kCameraFrameValues;
  }
  if (like.time) time = values_.select(0, offset);
  camera = camera_at_origin_of(like.camera);
}

void StepInputs::upload(const StepData& data) {
  const std::string kind = step_kind(data);
  TORCH_CHECK(kind == kind_, "StepInputs: the step is of another kind than these buffers: expected ", kind_, ", got ",
              kind);
  TORCH_CHECK(!data.time || (std::isfinite(*data.time) && *data.time >= -1 && *data.time <= 1),
              "StepInputs: the step's time must be in [-1, 1], got ", data.time.value_or(0.0));
  const bool cuda = values_.is_cuda();
  // Page-locked staging from LibTorch's caching host allocator: the copy is asynchronous, and the allocator does not
  // hand the block out again before the copy has read it.
  at::Tensor host = at::empty({values_.size(0)}, at::TensorOptions().dtype(at::kFloat).pinned_memory(cuda));
  float* v = host.data_ptr<float>();
  const at::Tensor pose_values = data.pose.packed();
  std::copy(pose_values.data_ptr<float>(), pose_values.data_ptr<float>() + pose_values_, v);
  int64_t offset = pose_values_;
  for (float c : data.background) v[offset++] = c;
  if (camera_frame.defined()) {
    write_camera_frame(data.camera, v + offset);
    offset += kCameraFrameValues;
  }
  if (time.defined()) v[offset++] = float(*data.time);
  values_.copy_(host, /*non_blocking=*/cuda);
  frame.copy_(data.frame, /*non_blocking=*/data.frame.is_pinned());
}

at::Tensor StepInputs::points_to_camera(const at::Tensor& points) const {
  return camera_frame.defined() ? camera_frame.points(points) : points;
}

at::Tensor StepInputs::directions_to_camera(const at::Tensor& directions) const {
  return camera_frame.defined() ? camera_frame.directions(directions) : directions;
}

at::Tensor StepInputs::covariances_to_camera(const at::Tensor& covariances) const {
  return camera_frame.defined() ? camera_frame.covariances(covariances) : covariances;
}

TrainingStep::TrainingStep(model::Avatar avatar, const ImageLoss& image_loss, const Regularisers& regularisers)
    : avatar_(std::move(avatar)), image_loss_(image_loss), regularisers_(regularisers) {}

StepOutputs TrainingStep::run(const StepInputs& in, bool lpips) {
  LossTerms terms;
  at::Tensor target;
  {
    const StageScope stage("train: target");
    const at::Tensor values = in.frame.to(at::kFloat).div_(float(kEightBitMax));
    const at::Tensor image = values.slice(2, 0, 3), mask = values.select(2, 3).unsqueeze(2);
    target = image * mask + in.background * (1 - mask);
  }
  // Gradients are dropped, not zeroed: a parameter a step does not reach (the time planes in a step without time)
  // then has none and Adam leaves it alone, in a resumed run (whose parameters start without gradients) exactly as
  // in an uninterrupted one; LibTorch versions differ in what zero_grad() does.
  for (at::Tensor& p : avatar_->parameters()) p.mutable_grad().reset();
  const model::AvatarOutput out = avatar_->forward_trusted_pose(in.pose, in.time);
  // Into the camera's frame on the device: the recorded launches then hold no camera pose.
  Gaussians gaussians = model::to_gaussians(out);
  gaussians.means = in.points_to_camera(gaussians.means);
  gaussians.covariances = in.covariances_to_camera(gaussians.covariances);
  const at::Tensor normals = in.directions_to_camera(out.posed_normals);
  StepOutputs result;
  RenderResult r;
  {
    const StageScope stage("train: render");
    RenderOptions options;
    if (in.budget) options.budget = &*in.budget;
    r = render(gaussians, in.background, in.camera, options);
  }
  {
    const StageScope stage("train: observation record");
    result.observation = model::frame_observation(gaussians.means, normals, r.depth, in.camera);
    result.footprint = model::frame_footprint(gaussians.means, in.camera);
  }
  {
    const StageScope stage("train: image loss");
    image_loss_.add_terms(r.image, target, terms, lpips);
  }
  at::Tensor loss;
  {
    const StageScope stage("train: regularisers");
    regularisers_.add_terms(out, terms);
    loss = total_loss(terms);
  }
  {
    const StageScope stage("train: backward");
    loss.backward();
  }
  result.psnr = metrics::psnr(r.image.detach(), target);
  result.terms = std::move(terms);
  return result;
}

}  // namespace sfgs::train
