// CPU binning stage: every Gaussian emits its (tile, Gaussian) intersections into its own range of slots, then a
// counting sort by tile and a stable sort of each tile's run by depth give the blends their front-to-back lists.
#include <algorithm>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "ops/splat/cpu/stages_cpu.h"

namespace sfgs::splat::cpu {
namespace {

constexpr int64_t kTilesPerTask = 16;

// Gaussian-major emission: Gaussian i fills slots [offsets[i], offsets[i + 1]) with its touched tiles, row-major.
template <typename T>
std::vector<int64_t> emit(const Projection& p, const TileGrid& grid, const int64_t* offsets, int64_t* isect_gaussian,
                          int64_t intersections) {
  std::vector<int64_t> isect_tile(static_cast<size_t>(intersections));
  const T* proj = p.projected.data_ptr<T>();
  const int64_t n = int64_t(p.tiles_touched.size());
  at::parallel_for(0, n, kGaussiansPerTask, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      if (p.tiles_touched[size_t(i)] == 0) continue;
      int64_t slot = offsets[i];
      count_touched_tiles(load_projected(proj + i * kProjectedWidth), p.tile_rects[size_t(i)], grid,
                          [&](int tx, int ty) {
                            isect_tile[size_t(slot)] = int64_t(ty) * grid.tiles_x + tx;
                            isect_gaussian[slot++] = i;
                          });
    }
  });
  return isect_tile;
}

// Counting sort by tile keeps Gaussian order within a tile; the per-tile sort by depth is then stable, so ties
// resolve by Gaussian index exactly as a stable (tile, depth) radix sort does.
template <typename T>
void sort_by_tile_and_depth(const std::vector<int64_t>& isect_tile, const int64_t* isect_gaussian, const T* proj,
                            int64_t* tile_offsets, int64_t* order, int64_t tiles) {
  const int64_t intersections = int64_t(isect_tile.size());
  for (int64_t s = 0; s < intersections; ++s) ++tile_offsets[isect_tile[size_t(s)] + 1];
  for (int64_t t = 0; t < tiles; ++t) tile_offsets[t + 1] += tile_offsets[t];
  {
    std::vector<int64_t> cursor(tile_offsets, tile_offsets + tiles);
    for (int64_t s = 0; s < intersections; ++s) order[cursor[size_t(isect_tile[size_t(s)])]++] = s;
  }
  at::parallel_for(0, tiles, kTilesPerTask, [&](int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t)
      std::stable_sort(order + tile_offsets[t], order + tile_offsets[t + 1], [&](int64_t a, int64_t b) {
        return proj[isect_gaussian[a] * kProjectedWidth + kDepth] < proj[isect_gaussian[b] * kProjectedWidth + kDepth];
      });
  });
}

}  // namespace

template <typename T> Binning bin(const Projection& p, const TileGrid& grid) {
  const int64_t n = int64_t(p.tiles_touched.size());
  const auto i64 = p.projected.options().dtype(at::kLong);
  Binning b;
  b.gaussian_offsets = at::empty({n + 1}, i64);
  int64_t* offsets = b.gaussian_offsets.data_ptr<int64_t>();
  offsets[0] = 0;
  for (int64_t i = 0; i < n; ++i) offsets[i + 1] = offsets[i] + p.tiles_touched[size_t(i)];
  const int64_t intersections = offsets[n];

  b.isect_gaussian = at::empty({intersections}, i64);
  int64_t* isect_gaussian = b.isect_gaussian.data_ptr<int64_t>();
  const std::vector<int64_t> isect_tile = emit<T>(p, grid, offsets, isect_gaussian, intersections);

  const int64_t tiles = tile_count(grid);
  b.tile_offsets = at::zeros({tiles + 1}, i64);
  b.tile_order = at::empty({intersections}, i64);
  sort_by_tile_and_depth(isect_tile, isect_gaussian, p.projected.data_ptr<T>(), b.tile_offsets.data_ptr<int64_t>(),
                         b.tile_order.data_ptr<int64_t>(), tiles);
  return b;
}

template Binning bin<float>(const Projection&, const TileGrid&);
template Binning bin<double>(const Projection&, const TileGrid&);

}  // namespace sfgs::splat::cpu
