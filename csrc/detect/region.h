#pragma once
// Regions of interest as MediaPipe's graphs use them, in image pixels: a rotated rectangle that a network's input is
// sampled from, and what maps the network's output back to the image (docs/prepare.md).
#include <array>
#include <cstdint>

#include <ATen/core/Tensor.h>

namespace sfgs::detect {

struct Region {
  double cx = 0, cy = 0;  // centre, pixels (pixel centres at +0.5)
  double width = 0, height = 0;
  double rotation = 0;  // radians; the region's x axis is the image's turned by this (y down: clockwise)

  // The image point of a point given in the region's unit square ((0, 0) top left, (1, 1) bottom right).
  std::array<double, 2> to_image(double u, double v) const;
  // Scaled about its centre; then, with `square_long`, widened to a square of its longer side.
  Region scaled(double factor, bool square_long) const;
  Region shifted(double along_x, double along_y) const;  // by these shares of its width and height, in its axes
};

// The rotation (in [-pi, pi)) that turns the direction a -> b to `target_angle` (angles counter-clockwise from the
// image's x axis, y up).
double alignment_rotation(double ax, double ay, double bx, double by, double target_angle);
// The region centred on `a` whose size is twice |b - a|, turned by alignment_rotation (MediaPipe's alignment-point
// rectangle).
Region alignment_region(double ax, double ay, double bx, double by, double target_angle);

enum class Border { kZero, kReplicate };

// The (N = 1, size, size, 3) float32 network input sampled bilinearly from `image` (H, W, 3) in [0, 1] over `region`
// (its pixels mapped to [low, high]), outside the image `border`.
at::Tensor crop(const at::Tensor& image, const Region& region, int64_t size, double low, double high, Border border);

// Points (K, 2) in a region's unit square as image pixels (K, 2).
at::Tensor points_to_image(const at::Tensor& unit_points, const Region& region);

// A map (size, size) over `region` resampled to the image's (height, width): zero outside the region.
at::Tensor map_to_image(const at::Tensor& map, const Region& region, int64_t height, int64_t width);

// The region a letterbox of the whole image fills: its centre, a square of its longer side.
Region letterbox(int64_t width, int64_t height);

}  // namespace sfgs::detect
