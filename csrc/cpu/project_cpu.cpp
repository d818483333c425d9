// CPU projection stage: project every Gaussian onto its tile rectangle, then count its touched tiles with the exact
// tile test.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "cpu/stages_cpu.h"

namespace sfgs::splat::cpu {
namespace {

constexpr int64_t kGaussiansPerTask = 256;

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
