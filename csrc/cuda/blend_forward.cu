// CUDA forward blend (rasterize_kernels.h): one block per tile, longest tiles first, one thread per pixel, front to
// back over the tile's sorted run.
#include <type_traits>

#include "cuda/blend_common.cuh"

namespace sfgs::splat::cuda_kernels {
namespace {

// Resident blocks per multiprocessor that the float kernel is register-limited for (40 registers, no spills); double
// keeps the compiler's choice.
template <typename T> constexpr int kForwardBlendBlocks = std::is_same_v<T, float> ? 6 : 1;

template <typename T, int kChannels> struct ForwardShared {
  T mean_x[kBlendThreads], mean_y[kBlendThreads];
  T conic_a[kBlendThreads], conic_b[kBlendThreads], conic_c[kBlendThreads];
  T opacity[kBlendThreads], depth[kBlendThreads], level[kBlendThreads];
  T features[kChannels][kBlendThreads];
};

template <typename T> struct BlendForwardParams {
  ForwardBuffers<T> b;
  const T* features;
  const T* background;
  int channels;
  TileGrid grid;
};

// One thread per pixel. Each warp walks the batch 32 Gaussians at a time: one ballot of the block test gives the
// Gaussians that can reach its pixel block, and only those are evaluated, in order, so every pixel sees exactly the
// pairs (and arithmetic) of the plain front-to-back loop.
template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads, kForwardBlendBlocks<T>)
    blend_forward_kernel(const BlendForwardParams<T> a, int channel_begin, int channel_count) {
  __shared__ ForwardShared<T, kChannels> sh;
  const int tile = a.b.tile_order[blockIdx.x];
  const int warp = threadIdx.x / kWarpSize, lane = threadIdx.x % kWarpSize;
  const TilePixel pixel = tile_pixel(tile, a.grid.tiles_x, threadIdx.x);
  const PixelBlock block = warp_block(tile, a.grid, warp);
  const int x = pixel.x, y = pixel.y;
  const bool inside = x < a.grid.width && y < a.grid.height;
  const T px = T(x) + T(kPixelCentre), py = T(y) + T(kPixelCentre);
  const int64_t begin = a.b.tile_offsets[tile], end = a.b.tile_offsets[tile + 1];

  T transmittance = T(1), depth = T(0);
  T colour[kChannels];
#pragma unroll
  for (int c = 0; c < kChannels; ++c) colour[c] = T(0);
  int32_t last = 0;
  bool done = !inside;
  for (int64_t batch = begin; batch < end; batch += kBlendThreads) {
    // Also the barrier that lets the previous batch's readers finish before it is overwritten.
    if (__syncthreads_count(done) == kBlendThreads) break;
    if (batch + threadIdx.x < end)
      store_batch_gaussian(sh, threadIdx.x, a.b.projected, a.b.isect_gaussian[batch + threadIdx.x], a.features,
                           a.channels, channel_begin, channel_count);
    __syncthreads();
    const int batch_size = int(smaller<int64_t>(kBlendThreads, end - batch));
    const int32_t batch_start = int32_t(batch - begin);
    for (int chunk = 0; chunk < batch_size; chunk += kWarpSize) {
      if (__all_sync(kFullWarp, done)) break;
      for (unsigned hits = __ballot_sync(kFullWarp, batch_touches_block(sh, chunk + lane, batch_size, block));
           hits != 0; hits &= hits - 1) {
        if (done) continue;
        const int j = chunk + __ffs(hits) - 1;
        const ProjectedGaussian<T> g = batch_gaussian(sh, j);
        PairAlpha<T> pair;
        if (!pair_alpha(g, px, py, pair)) continue;
        const T next = transmittance * (T(1) - pair.alpha);
        if (next < T(kMinTransmittance)) {
          done = true;
          continue;
        }
        const T weight = pair.alpha * transmittance;
#pragma unroll
        for (int c = 0; c < kChannels; ++c) colour[c] += weight * sh.features[c][j];
        depth += weight * g.depth;
        transmittance = next;
        last = batch_start + j + 1;
      }
    }
  }
  if (!inside) return;
  const int64_t pix = int64_t(y) * a.grid.width + x;
  T* image = a.b.image + pix * a.channels + channel_begin;
#pragma unroll
  for (int c = 0; c < kChannels; ++c)
    if (c < channel_count) image[c] = colour[c] + transmittance * a.background[channel_begin + c];
  if (channel_begin == 0) {
    a.b.alpha[pix] = T(1) - transmittance;
    a.b.depth_sum[pix] = depth;
    a.b.depth[pix] = expected_depth_of(depth, T(1) - transmittance);
    a.b.final_transmittance[pix] = transmittance;
    a.b.contributors[pix] = last;
  }
}

}  // namespace

template <typename T> void blend(const SplatScene<T>& s, const ForwardBuffers<T>& b, cudaStream_t stream) {
  const Stage stage("blend", stream);
  const BlendForwardParams<T> params{b, s.features, s.background, s.channels, grid_of(s)};
  const unsigned tiles = unsigned(tile_count(params.grid));
  for_each_channel_chunk(s.channels, [&](auto width, int channel_begin, int channel_count) {
    blend_forward_kernel<T, decltype(width)::value>
        <<<tiles, kBlendThreads, 0, stream>>>(params, channel_begin, channel_count);
    check_cuda(cudaGetLastError(), "blend_forward_kernel launch");
  });
}

template void blend<float>(const SplatScene<float>&, const ForwardBuffers<float>&, cudaStream_t);
template void blend<double>(const SplatScene<double>&, const ForwardBuffers<double>&, cudaStream_t);

}  // namespace sfgs::splat::cuda_kernels
