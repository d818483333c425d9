#include "model/planes.h"

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <ATen/core/grad_mode.h>

#include "body/tensor_checks.h"
#include "model/constants.h"

namespace sfgs::model {
namespace {

using plane_sampling::sample_planes;

at::Tensor random_planes(at::IntArrayRef shape) { return at::empty(shape).normal_(0.0, kPlaneInitStd); }

void check_coordinates(const at::Tensor& coordinates, const at::Tensor& planes, const char* what) {
  TORCH_CHECK(coordinates.defined() && coordinates.dim() == 2 && coordinates.size(1) == 3 &&
                  coordinates.scalar_type() == planes.scalar_type() && coordinates.device() == planes.device(),
              what, ": coordinates must be a ", planes.scalar_type(), " tensor of shape (N, 3) on ", planes.device(),
              ", got ", describe(coordinates));
}

}  // namespace

const plane_sampling::PlaneReads& FixedReadsCache::reads(const at::Tensor& coordinates,
                                                         const std::function<plane_sampling::PlaneReads()>& make) {
  const bool kept = coordinates_.defined() && coordinates_.is_same(coordinates) && data_ == coordinates.data_ptr() &&
                    version_ == int64_t(coordinates._version());
  if (!kept) {
    reads_ = make();
    coordinates_ = coordinates;
    data_ = coordinates.data_ptr();
    version_ = int64_t(coordinates._version());
  }
  return reads_;
}

TriplaneImpl::TriplaneImpl(int64_t channels, int64_t resolution) {
  TORCH_CHECK(channels > 0 && resolution > 1, "Triplane: channels must be positive and resolution at least 2, got ",
              channels, " and ", resolution);
  planes_ = register_parameter("planes", random_planes({3, channels, resolution, resolution}));
}

at::Tensor TriplaneImpl::sample(const at::Tensor& coordinates) const {
  check_coordinates(coordinates, planes_, "Triplane::sample");
  const at::Tensor x = coordinates.select(1, 0), y = coordinates.select(1, 1), z = coordinates.select(1, 2);
  const at::Tensor grid = at::stack({at::stack({x, y}, 1), at::stack({x, z}, 1), at::stack({y, z}, 1)});
  if (!planes_.requires_grad() || !at::GradMode::is_enabled() || coordinates.requires_grad())
    return sample_planes(planes_, grid);
  const plane_sampling::PlaneReads& reads =
      reads_.reads(coordinates, [&] { return plane_sampling::plane_reads(grid, planes_.size(2), planes_.size(3)); });
  return plane_sampling::sample_fixed_planes(planes_, grid, reads);
}

TimePlanesImpl::TimePlanesImpl(int64_t channels, int64_t resolution, int64_t time_resolution) {
  TORCH_CHECK(channels > 0 && resolution > 1 && time_resolution > 1,
              "TimePlanes: channels must be positive and both resolutions at least 2, got ", channels, ", ", resolution,
              " and ", time_resolution);
  planes_ = register_parameter("planes", random_planes({3, channels, time_resolution, resolution}));
}

at::Tensor TimePlanesImpl::sample(const at::Tensor& coordinates, const at::Tensor& time) const {
  check_coordinates(coordinates, planes_, "TimePlanes::sample");
  TORCH_CHECK(time.defined() && time.dim() == 0 && time.scalar_type() == planes_.scalar_type() &&
                  time.device() == planes_.device(),
              "TimePlanes::sample: the time must be a 0-dim ", planes_.scalar_type(), " tensor on ", planes_.device(),
              ", got ", describe(time));
  const at::Tensor positions = coordinates.t();  // (3, N): x, y, z, each along its plane's width
  if (!planes_.requires_grad() || !at::GradMode::is_enabled() || coordinates.requires_grad()) {
    return sample_planes(planes_, plane_sampling::time_grid(positions, time));
  }
  const plane_sampling::PlaneReads& reads = reads_.reads(coordinates, [&] {
    const at::Tensor line = at::stack({positions, at::full_like(positions, -1)}, -1);  // v plays no part
    return plane_sampling::plane_reads(line, 1, planes_.size(3));
  });
  return plane_sampling::sample_fixed_planes_at_time(planes_, positions, time, reads);
}

}  // namespace sfgs::model
