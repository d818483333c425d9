#include "model/planes.h"

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/tensor_checks.h"
#include "common/constants.h"

namespace sfgs::model {
namespace {

// at::grid_sampler's integer modes (torch.nn.functional.grid_sample's 'bilinear' and 'border').
constexpr int64_t kBilinear = 0;
constexpr int64_t kBorderPadding = 1;

at::Tensor random_planes(at::IntArrayRef shape) { return at::empty(shape).normal_(0.0, kPlaneInitStd); }

// planes (P, C, H, W) read at grid (P, N, 2) of (u along W, v along H) -> (N, P C), plane-major.
at::Tensor sample_planes(const at::Tensor& planes, const at::Tensor& grid) {
  const at::Tensor sampled = at::grid_sampler(planes, grid.unsqueeze(1), kBilinear, kBorderPadding,
                                              /*align_corners=*/true);  // (P, C, 1, N)
  return sampled.squeeze(2).permute({2, 0, 1}).reshape({grid.size(1), -1});
}

void check_coordinates(const at::Tensor& coordinates, const at::Tensor& planes, const char* what) {
  TORCH_CHECK(coordinates.defined() && coordinates.dim() == 2 && coordinates.size(1) == 3 &&
                  coordinates.scalar_type() == planes.scalar_type() && coordinates.device() == planes.device(),
              what, ": coordinates must be a ", planes.scalar_type(), " tensor of shape (N, 3) on ", planes.device(),
              ", got ", describe(coordinates));
}

}  // namespace

TriplaneImpl::TriplaneImpl(int64_t channels, int64_t resolution) {
  TORCH_CHECK(channels > 0 && resolution > 1, "Triplane: channels must be positive and resolution at least 2, got ",
              channels, " and ", resolution);
  planes_ = register_parameter("planes", random_planes({3, channels, resolution, resolution}));
}

at::Tensor TriplaneImpl::sample(const at::Tensor& coordinates) const {
  check_coordinates(coordinates, planes_, "Triplane::sample");
  const at::Tensor x = coordinates.select(1, 0), y = coordinates.select(1, 1), z = coordinates.select(1, 2);
  const at::Tensor grid = at::stack({at::stack({x, y}, 1), at::stack({x, z}, 1), at::stack({y, z}, 1)});
  return sample_planes(planes_, grid);
}

TimePlanesImpl::TimePlanesImpl(int64_t channels, int64_t resolution, int64_t time_resolution) {
  TORCH_CHECK(channels > 0 && resolution > 1 && time_resolution > 1,
              "TimePlanes: channels must be positive and both resolutions at least 2, got ", channels, ", ", resolution,
              " and ", time_resolution);
  planes_ = register_parameter("planes", random_planes({3, channels, time_resolution, resolution}));
}

at::Tensor TimePlanesImpl::sample(const at::Tensor& coordinates, double time) const {
  check_coordinates(coordinates, planes_, "TimePlanes::sample");
  const at::Tensor space = coordinates.t().unsqueeze(-1);  // (3, N, 1)
  const at::Tensor grid = at::cat({space, at::full_like(space, time)}, -1);
  return sample_planes(planes_, grid);
}

}  // namespace sfgs::model
