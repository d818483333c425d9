// CPU projection stage: project every Gaussian onto its tile rectangle, bound the work those rectangles could
// cost, then count each Gaussian's touched tiles with the exact tile test.
#include <cstdio>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "ops/splat/cpu/stages_cpu.h"
#include "ops/splat/constants.h"

namespace sfgs::splat::cpu {
namespace {

// The sum of the tile rectangles' areas bounds the Gaussian-tile pairs: the exact test visits every tile of every
// rectangle, and binning and backward hold state per pair that passes it. Refuses scenes past kCpuMaxTilePairs
// before any of that work starts.
void check_work_bound(const std::vector<PixelRect>& rects) {
  int64_t pairs = 0, largest = -1, gaussians = 0;
  for (size_t i = 0; i < rects.size(); ++i) {
    if (rect_empty(rects[i])) continue;
    ++gaussians;
    pairs += rect_area(rects[i]);
    if (largest < 0 || rect_area(rects[i]) > rect_area(rects[size_t(largest)])) largest = int64_t(i);
  }
  if (pairs <= kCpuMaxTilePairs) return;
  const PixelRect& r = rects[size_t(largest)];
  char bound[32], limit[32];
  std::snprintf(bound, sizeof(bound), "%.2g", double(pairs));
  std::snprintf(limit, sizeof(limit), "%.2g", double(kCpuMaxTilePairs));
  TORCH_CHECK(false, "sfgs::render (CPU): this image would need up to ", bound, " Gaussian-tile pairs (", gaussians,
              " Gaussians on screen, the largest covering ", r.x1 - r.x0 + 1, " x ", r.y1 - r.y0 + 1,
              " tiles), more than the CPU backend's limit of ", limit,
              "; render on CUDA, use a smaller image, or check the scales");
}

}  // namespace

template <typename T> Projection project(const SplatScene<T>& s, const TileGrid& grid, const at::TensorOptions& real) {
  const int64_t n = s.count;
  Projection p;
  p.projected = at::zeros({n, kProjectedWidth}, real);
  p.radii = at::zeros({n, 2}, real.dtype(at::kInt));
  p.tile_rects.assign(size_t(n), PixelRect{0, 0, -1, -1});  // empty: off the image or culled
  p.tiles_touched.assign(size_t(n), 0);
  T* proj = p.projected.data_ptr<T>();
  int32_t* rad = p.radii.data_ptr<int32_t>();
  at::parallel_for(0, n, kGaussiansPerTask, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      ProjectedGaussian<T> g;
      Vec2<T> radius;
      if (!project_to_tiles(s, i, g, p.tile_rects[size_t(i)], radius)) continue;
      store_projected(g, proj + i * kProjectedWidth);
      rad[2 * i] = pixel_radius(radius[0]);
      rad[2 * i + 1] = pixel_radius(radius[1]);
    }
  });
  check_work_bound(p.tile_rects);
  at::parallel_for(0, n, kGaussiansPerTask, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      if (rect_empty(p.tile_rects[size_t(i)])) continue;
      T* row = proj + i * kProjectedWidth;
      const int64_t touched = count_touched_tiles(load_projected(row), p.tile_rects[size_t(i)], grid, [](int, int) {});
      p.tiles_touched[size_t(i)] = touched;
      if (touched > 0) continue;
      std::fill(row, row + kProjectedWidth, T(0));
      rad[2 * i] = rad[2 * i + 1] = 0;
    }
  });
  return p;
}

template Projection project<float>(const SplatScene<float>&, const TileGrid&, const at::TensorOptions&);
template Projection project<double>(const SplatScene<double>&, const TileGrid&, const at::TensorOptions&);

}  // namespace sfgs::splat::cpu
