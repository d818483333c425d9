#pragma once
// What the forward and backward blends share: the pixel a thread of a tile's block covers, the pixel block of each
// warp, and the batch of Gaussians a block stages in shared memory.
#include <type_traits>

#include "ops/splat/cuda/kernel_common.cuh"
#include "ops/splat/constants.h"

namespace sfgs::splat::cuda_kernels {

// Each warp of a tile covers a compact 8 x 4 block of pixels, so that a Gaussian tends to cover all or none of a
// warp's pixels and the warp can skip it with one vote.
constexpr int kWarpBlockWidth = 8;
constexpr int kWarpBlockHeight = kWarpSize / kWarpBlockWidth;
constexpr int kWarpBlocksPerRow = kTileSize / kWarpBlockWidth;
static_assert(kTileSize % kWarpBlockWidth == 0 && kTileSize % kWarpBlockHeight == 0, "warp blocks must tile a tile");

struct TilePixel {
  int x, y;
};

__device__ inline TilePixel tile_pixel(int tile, int tiles_x, int thread) {
  const int warp = thread / kWarpSize, lane = thread % kWarpSize;
  return TilePixel{
      (tile % tiles_x) * kTileSize + (warp % kWarpBlocksPerRow) * kWarpBlockWidth + lane % kWarpBlockWidth,
      (tile / tiles_x) * kTileSize + (warp / kWarpBlocksPerRow) * kWarpBlockHeight + lane / kWarpBlockWidth};
}

// Inclusive pixel block of warp `warp` of a tile, clipped to the image (empty when it lies outside).
struct PixelBlock {
  int x0, y0, x1, y1;
};

__device__ inline PixelBlock warp_block(int tile, const TileGrid& grid, int warp) {
  PixelBlock b;
  b.x0 = (tile % grid.tiles_x) * kTileSize + (warp % kWarpBlocksPerRow) * kWarpBlockWidth;
  b.y0 = (tile / grid.tiles_x) * kTileSize + (warp / kWarpBlocksPerRow) * kWarpBlockHeight;
  b.x1 = smaller(b.x0 + kWarpBlockWidth, grid.width) - 1;
  b.y1 = smaller(b.y0 + kWarpBlockHeight, grid.height) - 1;
  return b;
}

// Stores Gaussian `gaussian` at batch position j of any of the shared layouts; Gaussian -1 (an unfilled slot) as one
// that touches no pixel.
template <typename Shared, typename T>
__device__ inline void store_batch_gaussian(Shared& sh, int j, const T* projected, int32_t gaussian, const T* features,
                                            int channels, int channel_begin, int channel_count) {
  constexpr int kChannels = std::extent<decltype(Shared::features)>::value;
  if (gaussian < 0) {
    sh.mean_x[j] = sh.mean_y[j] = sh.conic_a[j] = sh.conic_b[j] = sh.conic_c[j] = T(0);
    sh.opacity[j] = sh.depth[j] = T(0);
    sh.level[j] = T(-INFINITY);
#pragma unroll
    for (int c = 0; c < kChannels; ++c) sh.features[c][j] = T(0);
    return;
  }
  const T* p = projected + int64_t(gaussian) * kProjectedWidth;
  sh.mean_x[j] = p[kMeanX];
  sh.mean_y[j] = p[kMeanY];
  sh.conic_a[j] = p[kConicA];
  sh.conic_b[j] = p[kConicB];
  sh.conic_c[j] = p[kConicC];
  sh.opacity[j] = p[kOpacity];
  sh.depth[j] = p[kDepth];
  sh.level[j] = p[kLevel];
  const T* f = features + int64_t(gaussian) * channels + channel_begin;
#pragma unroll
  for (int c = 0; c < kChannels; ++c) sh.features[c][j] = c < channel_count ? f[c] : T(0);
}

template <typename Shared> __device__ inline auto batch_gaussian(const Shared& sh, int j) {
  using T = std::remove_cv_t<std::remove_reference_t<decltype(sh.mean_x[0])>>;
  ProjectedGaussian<T> g;
  g.mean = Vec2<T>(sh.mean_x[j], sh.mean_y[j]);
  g.conic = Vec3<T>(sh.conic_a[j], sh.conic_b[j], sh.conic_c[j]);
  g.opacity = sh.opacity[j];
  g.depth = sh.depth[j];
  g.level = sh.level[j];
  return g;
}

// Whether batch Gaussian j can reach any pixel of the block (false for positions past the batch).
template <typename Shared>
__device__ inline bool batch_touches_block(const Shared& sh, int j, int batch_size, const PixelBlock& block) {
  return j < batch_size && pixel_block_touched(batch_gaussian(sh, j), block.x0, block.y0, block.x1, block.y1);
}

}  // namespace sfgs::splat::cuda_kernels
