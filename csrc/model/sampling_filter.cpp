#include "model/sampling_filter.h"

#include <cmath>
#include <limits>

#include <ATen/ATen.h>

#include "ops/splat/constants.h"
#include "common/tensor_description.h"
#include "ops/splat/camera_frame.h"

namespace sfgs::model {
namespace {

double mean_focal(const Camera& camera) { return std::sqrt(camera.fx * camera.fy); }

}  // namespace

at::Tensor frame_footprint(const at::Tensor& means, const Camera& camera) {
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "frame_footprint: means must be (N, 3), got ", describe(means));
  at::NoGradGuard no_grad;
  const PixelView view = pixel_view(points_in_camera_frame(means.detach(), camera), camera);
  // A non-finite position is not in view.
  return at::where(view.inside, view.depth / mean_focal(camera),
                   at::full({}, std::numeric_limits<float>::infinity(), view.depth.options()));
}

at::Tensor sampling_record(const at::Tensor& minimum_footprint) {
  TORCH_CHECK(minimum_footprint.dim() == 1 && at::isFloatingType(minimum_footprint.scalar_type()),
              "sampling record: a floating (N) tensor expected, got ", describe(minimum_footprint));
  const at::Tensor f = minimum_footprint.detach().to(at::kFloat);
  TORCH_CHECK(!f.isnan().any().item<bool>() && (f >= 0).all().item<bool>(),
              "sampling record: footprints must be non-negative and not NaN");
  const at::Tensor held = f.isfinite();
  const double median = held.any().item<bool>() ? f.masked_select(held).median().item<double>() : 0.0;
  return at::where(held, f, at::full({}, median, f.options()));
}

at::Tensor sampling_filtered(const at::Tensor& covariances, const at::Tensor& means, const Camera& camera,
                             const at::Tensor& record) {
  TORCH_CHECK(covariances.dim() == 2 && covariances.size(1) == 6 && means.dim() == 2 && means.size(1) == 3 &&
                  means.size(0) == covariances.size(0) && record.sizes() == at::IntArrayRef{covariances.size(0)},
              "sampling_filtered: covariances (N, 6), means (N, 3) and a record (N) expected, got ",
              describe(covariances), ", ", describe(means), " and ", describe(record));
  // Each mean's depth in the camera's frame (a camera at the origin, as in a recorded frame, needs no transform).
  const at::Tensor footprint = points_in_camera_frame(means, camera).select(1, 2) / mean_focal(camera);
  const at::Tensor added =
      kLowPassVariancePx2 * (record.to(covariances.dtype()).square() - footprint.square()).clamp_min(0);
  // On the diagonal of (xx, xy, xz, yy, yz, zz); no host values, so that a recorded frame can hold it.
  const at::Tensor zero = at::zeros_like(added);
  return covariances + at::stack({added, zero, zero, added, zero, added}, 1);
}

}  // namespace sfgs::model
