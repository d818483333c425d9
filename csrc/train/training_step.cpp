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

namespace sfgs::train {
namespace {

// The upper triangle of a symmetric 3x3 matrix in the splatting op's order: xx, xy, xz, yy, yz, zz.
constexpr int kCovariancePairs[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
constexpr int64_t kBackgroundChannels = 3, kRotationValues = 9, kTranslationValues = 3, kCovarianceMapValues = 36;
constexpr int64_t kCameraValues = kRotationValues + kTranslationValues + kCovarianceMapValues;

// The (6, 6) matrix that turns a covariance's six values into those of R Sigma R^T: row (a, b), column (i, j) holds
// R_ai R_bj + R_aj R_bi (one term when i == j). Made on the host with the camera, so the device applies one product.
void covariance_map(const std::array<double, 16>& view, float* out) {
  const auto r = [&](int row, int column) { return view[size_t(4 * row + column)]; };
  for (int k = 0; k < 6; ++k) {
    const int a = kCovariancePairs[k][0], b = kCovariancePairs[k][1];
    for (int l = 0; l < 6; ++l) {
      const int i = kCovariancePairs[l][0], j = kCovariancePairs[l][1];
      double value = r(a, i) * r(b, j);
      if (i != j) value += r(a, j) * r(b, i);
      out[6 * k + l] = float(value);
    }
  }
}

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
  const int64_t count = pose_values_ + kBackgroundChannels + (moves ? kCameraValues : 0) + (like.time ? 1 : 0);
  values_ = at::empty({count}, options);
  pose = like.pose.views_of(values_.narrow(0, 0, pose_values_));
  int64_t offset = pose_values_;
  background = values_.narrow(0, offset, kBackgroundChannels);
  offset += kBackgroundChannels;
  if (moves) {
    world_to_camera = values_.narrow(0, offset, kRotationValues + kTranslationValues);
    offset += kRotationValues + kTranslationValues;
    covariance_rotation = values_.narrow(0, offset, kCovarianceMapValues).view({6, 6});
    offset += kCovarianceMapValues;
  }
  if (like.time) time = values_.select(0, offset);
  camera = like.camera;
  camera.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
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
  if (world_to_camera.defined()) {
    const auto& m = data.camera.world_to_camera;
    for (int row = 0; row < 3; ++row)
      for (int column = 0; column < 3; ++column) v[offset++] = float(m[size_t(4 * row + column)]);
    for (int row = 0; row < 3; ++row) v[offset++] = float(m[size_t(4 * row + 3)]);
    covariance_map(m, v + offset);
    offset += kCovarianceMapValues;
  }
  if (time.defined()) v[offset++] = float(*data.time);
  values_.copy_(host, /*non_blocking=*/cuda);
  frame.copy_(data.frame, /*non_blocking=*/data.frame.is_pinned());
}

at::Tensor StepInputs::points_to_camera(const at::Tensor& points) const {
  if (!world_to_camera.defined()) return points;
  const at::Tensor translation = world_to_camera.narrow(0, kRotationValues, kTranslationValues);
  return at::addmm(translation.unsqueeze(0), points, world_to_camera.narrow(0, 0, kRotationValues).view({3, 3}).t());
}

at::Tensor StepInputs::directions_to_camera(const at::Tensor& directions) const {
  if (!world_to_camera.defined()) return directions;
  return directions.matmul(world_to_camera.narrow(0, 0, kRotationValues).view({3, 3}).t());
}

at::Tensor StepInputs::covariances_to_camera(const at::Tensor& covariances) const {
  return world_to_camera.defined() ? covariances.matmul(covariance_rotation.t()) : covariances;
}

TrainingStep::TrainingStep(model::Avatar avatar, const ImageLoss& image_loss, const Regularisers& regularisers)
    : avatar_(std::move(avatar)), image_loss_(image_loss), regularisers_(regularisers) {}

StepOutputs TrainingStep::run(const StepInputs& in, const body::SmplxPose& pose, bool lpips, LossTerms terms,
                              const OutputTerms& output_terms) {
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
  const model::AvatarOutput out = avatar_->forward_trusted_pose(pose, in.time);
  // Into the camera's frame on the device: the recorded launches then hold no camera pose.
  Gaussians gaussians = model::to_gaussians(out);
  gaussians.means = in.points_to_camera(gaussians.means);
  gaussians.covariances = in.covariances_to_camera(gaussians.covariances);
  const at::Tensor normals = in.directions_to_camera(out.posed_normals);
  StepOutputs result;
  RenderResult r;
  {
    const StageScope stage("train: render");
    r = render(gaussians, in.background, in.camera);
  }
  {
    const StageScope stage("train: observation record");
    result.observation = model::frame_observation(gaussians.means, normals, r.depth, in.camera);
  }
  {
    const StageScope stage("train: image loss");
    image_loss_.add_terms(r.image, target, terms, lpips);
  }
  at::Tensor loss;
  {
    const StageScope stage("train: regularisers");
    regularisers_.add_terms(out, terms);
    if (output_terms) output_terms(out, terms);
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
