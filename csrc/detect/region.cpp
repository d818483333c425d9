#include "detect/region.h"

#include <algorithm>
#include <cmath>

#include <ATen/ATen.h>

#include "common/math_constants.h"
#include "common/tensor_description.h"

namespace sfgs::detect {
namespace {

// grid_sample's coordinates (align_corners false: -1 and 1 are the outer edges) of the image points (..., 2).
at::Tensor grid_coordinates(const at::Tensor& points, int64_t width, int64_t height) {
  const at::Tensor scale = at::tensor({2.0 / double(width), 2.0 / double(height)}, points.options());
  return points * scale - 1;
}

}  // namespace

std::array<double, 2> Region::to_image(double u, double v) const {
  const double x = (u - 0.5) * width, y = (v - 0.5) * height, c = std::cos(rotation), s = std::sin(rotation);
  return {cx + c * x - s * y, cy + s * x + c * y};
}

Region Region::scaled(double factor, bool square_long) const {
  Region r = *this;
  r.width *= factor;
  r.height *= factor;
  if (square_long) r.width = r.height = std::max(r.width, r.height);
  return r;
}

Region Region::shifted(double along_x, double along_y) const {
  Region r = *this;
  const double x = along_x * width, y = along_y * height, c = std::cos(rotation), s = std::sin(rotation);
  r.cx += c * x - s * y;
  r.cy += s * x + c * y;
  return r;
}

double alignment_rotation(double ax, double ay, double bx, double by, double target_angle) {
  const double angle = target_angle - std::atan2(-(by - ay), bx - ax);
  return angle - kTwoPi * std::floor((angle + kPi) / kTwoPi);
}

Region alignment_region(double ax, double ay, double bx, double by, double target_angle) {
  Region r;
  r.cx = ax;
  r.cy = ay;
  r.width = r.height = 2 * std::hypot(bx - ax, by - ay);
  r.rotation = alignment_rotation(ax, ay, bx, by, target_angle);
  return r;
}

at::Tensor crop(const at::Tensor& image, const Region& region, int64_t size, double low, double high, Border border) {
  TORCH_CHECK(image.dim() == 3 && image.size(2) == 3 && image.scalar_type() == at::kFloat,
              "crop: a float32 (H, W, 3) image expected, got ", describe(image));
  const at::TensorOptions options = image.options();
  // Pixel centres of the output in the region's unit square, then in the image.
  const at::Tensor t = (at::arange(size, options) + 0.5) / double(size);
  const std::vector<at::Tensor> vu = at::meshgrid({t, t}, "ij");
  const at::Tensor unit = at::stack({vu[1], vu[0]}, 2).view({-1, 2});
  const at::Tensor grid =
      grid_coordinates(points_to_image(unit, region), image.size(1), image.size(0)).view({1, size, size, 2});
  const at::Tensor nchw = image.permute({2, 0, 1}).unsqueeze(0);
  const at::Tensor sampled =
      at::grid_sampler(nchw, grid, /*bilinear*/ 0, border == Border::kZero ? /*zeros*/ 0 : /*border*/ 1,
                       /*align_corners*/ false);
  return sampled.permute({0, 2, 3, 1}).contiguous() * (high - low) + low;
}

at::Tensor points_to_image(const at::Tensor& unit_points, const Region& region) {
  const double c = std::cos(region.rotation), s = std::sin(region.rotation);
  const at::Tensor local = (unit_points - 0.5) * at::tensor({region.width, region.height}, unit_points.options());
  const at::Tensor turn = at::tensor({c, s, -s, c}, unit_points.options()).view({2, 2});  // rows: x', y' of (x, y)^T
  return local.matmul(turn) + at::tensor({region.cx, region.cy}, unit_points.options());
}

at::Tensor map_to_image(const at::Tensor& map, const Region& region, int64_t height, int64_t width) {
  const at::TensorOptions options = map.options();
  const std::vector<at::Tensor> yx =
      at::meshgrid({at::arange(height, options) + 0.5, at::arange(width, options) + 0.5}, "ij");
  const at::Tensor points = at::stack({yx[1], yx[0]}, 2).view({-1, 2}) - at::tensor({region.cx, region.cy}, options);
  const double c = std::cos(region.rotation), s = std::sin(region.rotation);
  // Into the region's axes (the inverse rotation), then its unit square.
  const at::Tensor turn = at::tensor({c, -s, s, c}, options).view({2, 2});
  const at::Tensor unit = points.matmul(turn) / at::tensor({region.width, region.height}, options) + 0.5;
  const at::Tensor grid = (unit * 2 - 1).view({1, height, width, 2});
  return at::grid_sampler(map.view({1, 1, map.size(0), map.size(1)}), grid, 0, 0, false).view({height, width});
}

Region letterbox(int64_t width, int64_t height) {
  Region r;
  r.cx = 0.5 * double(width);
  r.cy = 0.5 * double(height);
  r.width = r.height = double(std::max(width, height));
  return r;
}

}  // namespace sfgs::detect
