#pragma once
// The CPU reference backend's stages, in pipeline order (rasterize_cpu.cpp runs them):
//   project_cpu.cpp         project every Gaussian, refuse absurd workloads, count each one's touched tiles
//   binning_cpu.cpp         emit (tile, Gaussian) intersections Gaussian-major, sort them by (tile, depth, Gaussian)
//   blend_forward_cpu.cpp   blend each tile front to back
//   blend_backward_cpu.cpp  replay each pixel's blend, write every pair's gradient into its intersection's slot, sum
//                           the slots per Gaussian
// Every stage is parallel over Gaussians or tiles (at::parallel_for) and deterministic for any thread count: every
// reduction has a fixed order. Templates are instantiated for float and double in their own files.
#include <algorithm>
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

#include "ops/splat/backend.h"
#include "ops/splat/constants.h"

namespace sfgs::splat::cpu {

constexpr int kTilePixels = kTileSize * kTileSize;
// Gaussians one parallel task takes in the per-Gaussian stages: enough work to pay for a task.
constexpr int64_t kGaussiansPerTask = 256;

// ---- projection ------------------------------------------------------------------------------------------------

struct Projection {
  at::Tensor projected;                // (N, kProjectedWidth) ProjectedField rows; rows of culled Gaussians zero
  at::Tensor radii;                    // (N, 2) int32; 0 for culled Gaussians
  std::vector<PixelRect> tile_rects;   // inclusive tile rectangle of each Gaussian that touches a tile
  std::vector<int64_t> tiles_touched;  // tiles each Gaussian touches (exact test); 0: culled
};

// Refuses (c10::Error) a scene whose Gaussian-tile pairs could exceed kCpuMaxTilePairs before testing any tile.
template <typename T>
Projection project(const SplatScene<T>& scene, const TileGrid& grid, const at::TensorOptions& real);

// ---- binning -----------------------------------------------------------------------------------------------------

// Intersections in emission order: Gaussian i owns [gaussian_offsets[i], gaussian_offsets[i + 1]), its tiles
// row-major; that index is also the intersection's gradient slot.
struct Binning {
  at::Tensor gaussian_offsets;  // (N + 1) int64
  at::Tensor isect_gaussian;    // (intersections) int64
  at::Tensor tile_offsets;      // (tiles + 1) int64: start of each tile's run in tile_order
  at::Tensor tile_order;        // (intersections) int64: intersections sorted by (tile, depth, Gaussian)
};

template <typename T> Binning bin(const Projection& projection, const TileGrid& grid);

// ---- blending ------------------------------------------------------------------------------------------------------

struct BlendOutputs {
  at::Tensor image, alpha, depth, final_transmittance, contributors;  // see ForwardOutputs and ForwardContext
};

// The projected rows and intersection lists both blends read.
template <typename T> struct TileLists {
  const T* projected;
  const int64_t* isect_gaussian;
  const int64_t* tile_offsets;
  const int64_t* tile_order;
};

template <typename T>
BlendOutputs blend_forward(const SplatScene<T>& scene, const TileGrid& grid, const TileLists<T>& lists);

// Gradients w.r.t. the outputs, as arrays of the inputs' type (never null: zeros where none flows).
template <typename T> struct OutputGradientArrays {
  const T* image;      // (H, W, C)
  const T* alpha;      // (H, W)
  const T* depth_sum;  // (H, W)
};

// Writes every input gradient. final_transmittance and contributors: the forward blend's.
template <typename T>
void blend_backward(const SplatScene<T>& scene, const TileGrid& grid, const TileLists<T>& lists,
                    const int64_t* gaussian_offsets, int64_t intersections, const T* final_transmittance,
                    const int32_t* contributors, const OutputGradientArrays<T>& grads, const Gradients<T>& out);

// ---- what both blends share ----------------------------------------------------------------------------------------

// Pixels a projected Gaussian can reach with alpha >= kMinAlpha, widened by one pixel so rounding at the ellipse's
// edge can never drop a pixel the pair test would keep: every pixel outside has sigma well above the level.
template <typename T> PixelRect reachable_pixels(const ProjectedGaussian<T>& g, int width, int height) {
  const T det = g.conic[0] * g.conic[2] - g.conic[1] * g.conic[1];
  PixelRect r = pixel_rect(g, g.conic[2] / det, g.conic[0] / det, width, height);
  r.x0 = std::max(0, r.x0 - 1);
  r.y0 = std::max(0, r.y0 - 1);
  r.x1 = std::min(width - 1, r.x1 + 1);
  r.y1 = std::min(height - 1, r.y1 + 1);
  return r;
}

// One entry of a tile's depth-ordered list, with the part of the tile it can reach.
template <typename T> struct TileEntry {
  ProjectedGaussian<T> g;
  int64_t slot;        // emission slot (gradient slot) of this intersection
  int x0, y0, x1, y1;  // reachable pixels inside the tile, tile-local
};

// Origin and size (clipped to the image) of a tile.
struct TileBox {
  int x0, y0, width, height;
};

inline TileBox tile_box(const TileGrid& grid, int64_t tile) {
  const int x0 = int(tile % grid.tiles_x) * kTileSize, y0 = int(tile / grid.tiles_x) * kTileSize;
  return TileBox{x0, y0, std::min(kTileSize, grid.width - x0), std::min(kTileSize, grid.height - y0)};
}

// The tile's list entries [begin, end) with their reachable pixels clipped to the tile; entries reaching none of the
// tile's pixels are kept (as empty rectangles) so list positions stay those of the forward pass.
template <typename T>
void gather_tile(const TileGrid& grid, int64_t tile, const TileLists<T>& lists, int64_t begin, int64_t end,
                 std::vector<TileEntry<T>>& out) {
  const TileBox box = tile_box(grid, tile);
  out.clear();
  for (int64_t k = begin; k < end; ++k) {
    TileEntry<T> e;
    e.slot = lists.tile_order[k];
    e.g = load_projected(lists.projected + lists.isect_gaussian[e.slot] * kProjectedWidth);
    const PixelRect r = reachable_pixels(e.g, grid.width, grid.height);
    e.x0 = std::max(r.x0 - box.x0, 0);
    e.y0 = std::max(r.y0 - box.y0, 0);
    e.x1 = std::min(r.x1 - box.x0, kTileSize - 1);
    e.y1 = std::min(r.y1 - box.y0, kTileSize - 1);
    out.push_back(e);
  }
}

}  // namespace sfgs::splat::cpu
