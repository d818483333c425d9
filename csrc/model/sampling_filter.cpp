#include "model/sampling_filter.h"

#include <cmath>
#include <limits>
#include <vector>

#include <ATen/ATen.h>

#include "common/constants.h"
#include "common/tensor_description.h"

namespace sfgs::model {
namespace {

double mean_focal(const Camera& camera) { return std::sqrt(camera.fx * camera.fy); }

}  // namespace

at::Tensor frame_footprint(const at::Tensor& means, const Camera& camera) {
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "frame_footprint: means must be (N, 3), got ", describe(means));
  at::NoGradGuard no_grad;
  at::Tensor p = means.detach();
  if (!camera_at_origin(camera)) {
    const auto& m = camera.world_to_camera;
    const at::Tensor view =
        at::tensor(std::vector<double>(m.begin(), m.end()), at::kDouble).view({4, 4}).to(p.options());
    p = p.matmul(view.slice(0, 0, 3).slice(1, 0, 3).t()) + view.slice(0, 0, 3).select(1, 3);
  }
  const at::Tensor z = p.select(1, 2);
  const at::Tensor safe_z = z.clamp_min(camera.near_plane);
  const at::Tensor u = camera.fx * p.select(1, 0) / safe_z + camera.cx;
  const at::Tensor v = camera.fy * p.select(1, 1) / safe_z + camera.cy;
  // NaN positions compare false: not in view.
  const at::Tensor inside =
      (z > camera.near_plane) & (u >= 0) & (u < double(camera.width)) & (v >= 0) & (v < double(camera.height));
  return at::where(inside, safe_z / mean_focal(camera),
                   at::full({}, std::numeric_limits<float>::infinity(), z.options()));
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
  at::Tensor depth = means.select(1, 2);
  if (!camera_at_origin(camera)) {
    const auto& m = camera.world_to_camera;
    depth = means.matmul(at::tensor({m[8], m[9], m[10]}, at::kDouble).to(means.options())) + m[11];
  }
  const at::Tensor footprint = depth / mean_focal(camera);
  const at::Tensor added =
      kLowPassVariancePx2 * (record.to(covariances.dtype()).square() - footprint.square()).clamp_min(0);
  // On the diagonal of (xx, xy, xz, yy, yz, zz); no host values, so that a recorded frame can hold it.
  const at::Tensor zero = at::zeros_like(added);
  return covariances + at::stack({added, zero, zero, added, zero, added}, 1);
}

}  // namespace sfgs::model
