// CUDA backward (rasterize_kernels.h): the backward blend, one block per tile replaying every pixel's blend front to
// back, then one thread per Gaussian turning its summed projected gradient into input gradients (ops/splat/stages.h),
// and the background gradient.
#include <type_traits>

#include "ops/splat/cuda/blend_common.cuh"
#include "ops/splat/constants.h"

namespace sfgs::splat::cuda_kernels {
namespace {

// Resident blocks per multiprocessor that the float backward blend is register-limited for (48 registers); double
// keeps the compiler's choice.
template <typename T> constexpr int kBackwardBlendBlocks = std::is_same_v<T, float> ? 5 : 1;
// Gaussians per backward batch: one ballot covers a batch.
constexpr int kBackwardBatch = kWarpSize;

template <typename T, int kChannels> struct BackwardShared {
  // A batch of the tile's Gaussians.
  T mean_x[kBackwardBatch], mean_y[kBackwardBatch];
  T conic_a[kBackwardBatch], conic_b[kBackwardBatch], conic_c[kBackwardBatch];
  T opacity[kBackwardBatch], depth[kBackwardBatch], level[kBackwardBatch];
  T features[kChannels][kBackwardBatch];
  int32_t gaussian[kBackwardBatch];
  // Each warp's gradient sum for each Gaussian of the batch: projected-gradient fields, then the chunk's features;
  // written only where bit j of warp_contributed[warp] is set.
  T warp_grad[kBlendWarps][kBackwardBatch][kReducedValues];
  uint32_t warp_contributed[kBlendWarps];
  T warp_background[kBlendWarps][kChannels];
  int32_t max_last;
};

template <typename T> struct BlendBackwardParams {
  BackwardInputs<T> in;
  const T* features;
  int channels;
  TileGrid grid;
  bool deterministic;
  T* grad_projected;       // (N, kProjectedGradWidth) atomically accumulated, when not deterministic
  T* grad_features;        // (N, C) atomically accumulated, when not deterministic
  T* slots;                // (intersections, kProjectedGradWidth + C), when deterministic
  int32_t* tile_limits;    // (tiles) intersections of the tile that any pixel blended
  T* background_partials;  // (tiles, C)
};

// One thread per pixel replays the forward blend front to back (the same transmittances, no division), so every
// pair sees its exact state: what lies behind it is the pixel's total minus what has been blended so far. Per batch
// of 32 Gaussians one ballot gives the Gaussians that can reach the warp's pixel block before its last blended one;
// a vote skips those that none of its pixels blended. A warp's pixel contributions to one Gaussian are summed in

// ---- backward blend -------------------------------------------------------------------------------------------

// What the replay of one thread's pixel reads, for the channel chunk [channel_begin, channel_begin + channel_count).
template <typename T, int kChannels> struct PixelGradients {
  bool inside;
  int64_t pix;
  int32_t last;  // run position + 1 of the pixel's last blended Gaussian
  T grad_colour[kChannels];
  T total_dot;  // image . grad_image over the chunk's channels: everything blended, background included
  T final_t, grad_depth, grad_alpha, depth_sum;
};

template <typename T, int kChannels>
__device__ __forceinline__ PixelGradients<T, kChannels> load_pixel(const BlendBackwardParams<T>& a,
                                                                   const TilePixel& pixel, int channel_begin,
                                                                   int channel_count) {
  const BackwardInputs<T>& in = a.in;
  const bool first_chunk = channel_begin == 0;
  PixelGradients<T, kChannels> p;
  p.inside = pixel.x < a.grid.width && pixel.y < a.grid.height;
  p.pix = int64_t(pixel.y) * a.grid.width + pixel.x;
  p.last = p.inside ? in.contributors[p.pix] : 0;
  p.total_dot = T(0);
#pragma unroll
  for (int c = 0; c < kChannels; ++c) {
    const bool used = p.inside && in.grad_image != nullptr && c < channel_count;
    p.grad_colour[c] = used ? in.grad_image[p.pix * a.channels + channel_begin + c] : T(0);
    if (used) p.total_dot += in.image[p.pix * a.channels + channel_begin + c] * p.grad_colour[c];
  }
  p.final_t = p.inside ? in.final_transmittance[p.pix] : T(0);
  p.grad_depth = p.inside && first_chunk && in.grad_depth_sum != nullptr ? in.grad_depth_sum[p.pix] : T(0);
  p.grad_alpha = p.inside && first_chunk && in.grad_alpha != nullptr ? in.grad_alpha[p.pix] : T(0);
  p.depth_sum = p.inside ? in.depth_sum[p.pix] : T(0);
  return p;
}

// Writes the tile's background partial for the chunk and returns how far into the tile's run any pixel blended.
template <typename T, int kChannels>
__device__ __forceinline__ int32_t tile_prologue(const BlendBackwardParams<T>& a, BackwardShared<T, kChannels>& sh,
                                                 int tile, const PixelGradients<T, kChannels>& p, int32_t warp_last,
                                                 int channel_begin, int channel_count) {
  const int tid = threadIdx.x, warp = tid / kWarpSize, lane = tid % kWarpSize;
  if (tid == 0) sh.max_last = 0;
#pragma unroll
  for (int c = 0; c < kChannels; ++c) {
    const T partial = warp_sum(p.final_t * p.grad_colour[c]);
    if (lane == 0) sh.warp_background[warp][c] = partial;
  }
  __syncthreads();
  if (lane == 0) atomicMax(&sh.max_last, warp_last);
  if (tid < channel_count) {
    T sum = T(0);
    for (int w = 0; w < kBlendWarps; ++w) sum += sh.warp_background[w][tid];
    a.background_partials[int64_t(tile) * a.channels + channel_begin + tid] = sum;
  }
  __syncthreads();
  const int32_t limit = sh.max_last;
  if (channel_begin == 0 && tid == 0) a.tile_limits[tile] = limit;
  return limit;
}

// The replay's running state: transmittance before the next pair, and what has been blended so far.
template <typename T> struct Replay { T transmittance, running_dot, running_depth; };

// One blended pair's gradient values (ProjectedGradField, then the chunk's features) into grad; advances the replay.
template <typename T, int kChannels>
__device__ __forceinline__ void pair_gradient(const BackwardShared<T, kChannels>& sh, int j,
                                              const ProjectedGaussian<T>& g, const PairAlpha<T>& pair,
                                              const PixelGradients<T, kChannels>& p, Replay<T>& r,
                                              T (&grad)[kReducedValues]) {
  const T weight = pair.alpha * r.transmittance;
  T dot = T(0);
#pragma unroll
  for (int c = 0; c < kChannels; ++c) {
    dot += sh.features[c][j] * p.grad_colour[c];
    grad[kProjectedGradWidth + c] = weight * p.grad_colour[c];
  }
  r.running_dot += weight * dot;
  r.running_depth += weight * g.depth;
  grad[kGradDepth] = weight * p.grad_depth;
  const T grad_pair_alpha = composite_grad_alpha(pair.alpha, r.transmittance, dot, p.total_dot - r.running_dot, g.depth,
                                                 p.grad_depth, p.depth_sum - r.running_depth, p.final_t, p.grad_alpha);
  Vec2<T> grad_mean(T(0));
  Vec3<T> grad_conic(T(0));
  T grad_opacity = T(0);
  pair_alpha_vjp(g, pair, grad_pair_alpha, grad_mean, grad_conic, grad_opacity);
  grad[kGradMeanX] = grad_mean[0];
  grad[kGradMeanY] = grad_mean[1];
  grad[kGradConicA] = grad_conic[0];
  grad[kGradConicB] = grad_conic[1];
  grad[kGradConicC] = grad_conic[2];
  grad[kGradOpacity] = grad_opacity;
  r.transmittance *= T(1) - pair.alpha;
}

// The warp's pass over the staged batch: per Gaussian that can reach its block before its pixels' last blended one,
// the warp's sum of its pixels' gradients into sh.warp_grad. Returns the Gaussians some pixel of the warp blended.
template <typename T, int kChannels>
__device__ __forceinline__ uint32_t warp_batch_gradients(BackwardShared<T, kChannels>& sh, int32_t batch, int reach,
                                                         const PixelBlock& block, T px, T py,
                                                         const PixelGradients<T, kChannels>& p, Replay<T>& r) {
  constexpr int kValues = kProjectedGradWidth + kChannels;
  const int warp = threadIdx.x / kWarpSize, lane = threadIdx.x % kWarpSize;
  uint32_t contributed = 0;
  for (unsigned hits = __ballot_sync(kFullWarp, batch_touches_block(sh, lane, reach, block)); hits != 0;
       hits &= hits - 1) {
    const int j = __ffs(hits) - 1;
    const ProjectedGaussian<T> g = batch_gaussian(sh, j);
    PairAlpha<T> pair;
    const bool blended = batch + j < p.last && pair_alpha(g, px, py, pair);
    if (!__any_sync(kFullWarp, blended)) continue;
    contributed |= 1u << j;
    T grad[kReducedValues];
#pragma unroll
    for (int f = 0; f < kReducedValues; ++f) grad[f] = T(0);
    if (blended) pair_gradient(sh, j, g, pair, p, r, grad);
    const T total = warp_transpose_sum(grad, lane);
    if (lane % 2 == 0 && lane / 2 < kValues) sh.warp_grad[warp][j][lane / 2] = total;
  }
  return contributed;
}

// Gaussian j's gradient over the tile: the contributing warps' sums, added in warp order, then into its
// intersection's slot (deterministic) or its accumulators.
template <typename T, int kChannels>
__device__ __forceinline__ void add_batch_gradients(const BlendBackwardParams<T>& a,
                                                    const BackwardShared<T, kChannels>& sh, int64_t first_slot,
                                                    int batch_size, int channel_begin, int channel_count) {
  constexpr int kValues = kProjectedGradWidth + kChannels;
  for (int item = threadIdx.x; item < batch_size * kValues; item += kBlendThreads) {
    const int j = item / kValues, f = item % kValues;
    T sum = T(0);
    for (int w = 0; w < kBlendWarps; ++w)
      if ((sh.warp_contributed[w] >> j) & 1u) sum += sh.warp_grad[w][j][f];
    const bool feature = f >= kProjectedGradWidth;
    const int channel = channel_begin + f - kProjectedGradWidth;
    if (feature && f - kProjectedGradWidth >= channel_count) continue;
    if (a.deterministic) {
      T* slot = a.slots + (first_slot + j) * (kProjectedGradWidth + a.channels);
      if (feature)
        slot[kProjectedGradWidth + channel] = sum;
      else
        slot[f] = channel_begin == 0 ? sum : slot[f] + sum;
    } else if (sum != T(0)) {
      const int64_t gaussian = sh.gaussian[j];
      atomicAdd(feature ? a.grad_features + gaussian * a.channels + channel
                        : a.grad_projected + gaussian * kProjectedGradWidth + f,
                sum);
    }
  }
}

// One thread per pixel replays the forward blend front to back (the same transmittances, no division), so every
// pair sees its exact state: what lies behind it is the pixel's total minus what has been blended so far. Per batch
// of 32 Gaussians one ballot gives the Gaussians that can reach the warp's pixel block before its last blended one;
// a vote skips those that none of its pixels blended. A warp's pixel contributions to one Gaussian are summed in
// registers; the contributing warps' sums are added in warp order, once per (tile, Gaussian).
template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads, kBackwardBlendBlocks<T>)
    blend_backward_kernel(const BlendBackwardParams<T> a, int channel_begin, int channel_count) {
  static_assert(kProjectedGradWidth + kChannels <= kReducedValues,
                "a Gaussian's gradient values must fit the warp reduction");
  __shared__ BackwardShared<T, kChannels> sh;
  const int tid = threadIdx.x, warp = tid / kWarpSize, lane = tid % kWarpSize;
  const int tile = a.in.tile_order[blockIdx.x];
  const TilePixel pixel = tile_pixel(tile, a.grid.tiles_x, tid);
  const PixelBlock block = warp_block(tile, a.grid, warp);
  const int64_t begin = a.in.tile_offsets[tile];
  const PixelGradients<T, kChannels> p = load_pixel<T, kChannels>(a, pixel, channel_begin, channel_count);
  const int32_t warp_last = int32_t(__reduce_max_sync(kFullWarp, unsigned(p.last)));
  const int32_t limit = tile_prologue(a, sh, tile, p, warp_last, channel_begin, channel_count);

  const T px = T(pixel.x) + T(kPixelCentre), py = T(pixel.y) + T(kPixelCentre);
  Replay<T> r{T(1), T(0), T(0)};
  for (int32_t batch = 0; batch < limit; batch += kBackwardBatch) {
    const int batch_size = int(smaller<int32_t>(kBackwardBatch, limit - batch));
    if (tid < batch_size) {
      const int32_t gaussian = a.in.isect_gaussian[begin + batch + tid];
      sh.gaussian[tid] = gaussian;
      store_batch_gaussian(sh, tid, a.in.projected, gaussian, a.features, a.channels, channel_begin, channel_count);
    }
    __syncthreads();
    const int reach = int(smaller<int32_t>(batch_size, warp_last - batch));  // past it no pixel of the warp blends
    const uint32_t contributed = warp_batch_gradients(sh, batch, reach, block, px, py, p, r);
    if (lane == 0) sh.warp_contributed[warp] = contributed;
    __syncthreads();
    add_batch_gradients(a, sh, begin + batch, batch_size, channel_begin, channel_count);
    __syncthreads();
  }
}

// ---- backward per Gaussian ------------------------------------------------------------------------------------

template <typename T> struct ProjectBackwardParams {
  BackwardInputs<T> in;
  Gradients<T> out;
  TileGrid grid;
  bool deterministic;
  const T* grad_projected;
  const T* slots;
  const int32_t* tile_limits;
};

// Position of Gaussian `gaussian` (depth `depth`) among a tile's blended intersections, -1 if absent. Within a tile
// the intersections are sorted by (depth, index), and the blended ones are never Gaussian -1.
template <typename T>
__device__ int64_t find_intersection(const ProjectBackwardParams<T>& a, int64_t tile, T depth, int32_t gaussian) {
  int64_t lo = a.in.tile_offsets[tile], hi = lo + a.tile_limits[tile];
  while (lo < hi) {
    const int64_t mid = lo + (hi - lo) / 2;
    const int32_t other = a.in.isect_gaussian[mid];
    if (other == gaussian) return mid;
    const T other_depth = a.in.projected[int64_t(other) * kProjectedWidth + kDepth];
    if (other_depth < depth || (other_depth == depth && other < gaussian))
      lo = mid + 1;
    else
      hi = mid;
  }
  return -1;
}

// Sums Gaussian i's slots over the tiles of its rectangle into grad and its feature gradients (deterministic mode).
template <typename T>
__device__ void sum_slots(const ProjectBackwardParams<T>& a, int64_t i, int channels, const TileRect& r,
                          T (&grad)[kProjectedGradWidth]) {
  T* grad_features = a.out.features + i * channels;
  for (int c = 0; c < channels; ++c) grad_features[c] = T(0);
  if (!rect_has_tiles(r)) return;
  const T depth = a.in.projected[i * kProjectedWidth + kDepth];
  for (int ty = r.y0; ty <= r.y1; ++ty)
    for (int tx = r.x0; tx <= r.x1; ++tx) {
      const int64_t k = find_intersection(a, int64_t(ty) * a.grid.tiles_x + tx, depth, int32_t(i));
      if (k < 0) continue;
      const T* slot = a.slots + k * (kProjectedGradWidth + channels);
#pragma unroll
      for (int f = 0; f < kProjectedGradWidth; ++f) grad[f] += slot[f];
      for (int c = 0; c < channels; ++c) grad_features[c] += slot[kProjectedGradWidth + c];
    }
}

template <typename T> __global__ void project_backward_kernel(const SplatScene<T> s, const ProjectBackwardParams<T> a) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= s.count) return;
  const TileRect r = a.in.tile_rects[i];
  const bool visible = rect_has_tiles(r);
  T grad[kProjectedGradWidth];
#pragma unroll
  for (int f = 0; f < kProjectedGradWidth; ++f) grad[f] = T(0);
  if (a.deterministic) {
    sum_slots(a, i, s.channels, r, grad);
  } else if (visible) {
#pragma unroll
    for (int f = 0; f < kProjectedGradWidth; ++f) grad[f] = a.grad_projected[i * kProjectedGradWidth + f];
  }
  if (visible)
    write_input_gradients(s, i, grad, a.out);
  else
    write_zero_gradients(s, i, a.out);
}

// Sums the per-tile background partials of channel blockIdx.x in a fixed order.
template <typename T>
__global__ void __launch_bounds__(kLinearThreads)
    background_grad_kernel(const T* partials, int64_t tiles, int channels, T* grad_background) {
  __shared__ T warp_sums[kLinearThreads / kWarpSize];
  const int c = blockIdx.x;
  T sum = T(0);
  for (int64_t t = threadIdx.x; t < tiles; t += kLinearThreads) sum += partials[t * channels + c];
  sum = warp_sum(sum);
  if (threadIdx.x % kWarpSize == 0) warp_sums[threadIdx.x / kWarpSize] = sum;
  __syncthreads();
  if (threadIdx.x != 0) return;
  T total = T(0);
  for (int w = 0; w < kLinearThreads / kWarpSize; ++w) total += warp_sums[w];
  grad_background[c] = total;
}

}  // namespace

template <typename T>
void backward(const SplatScene<T>& s, const BackwardInputs<T>& in, const Gradients<T>& out, bool deterministic,
              const ScratchAllocator& scratch, cudaStream_t stream) {
  const TileGrid grid = grid_of(s);
  const int64_t tiles = tile_count(grid);
  BlendBackwardParams<T> blend{in,      s.features, s.channels, grid,    deterministic,
                               nullptr, nullptr,    nullptr,    nullptr, nullptr};
  blend.tile_limits = allocate<int32_t>(scratch, tiles);
  blend.background_partials = allocate<T>(scratch, tiles * s.channels);
  if (deterministic) {
    blend.slots = allocate<T>(scratch, in.intersection_count * (kProjectedGradWidth + s.channels));
  } else {
    blend.grad_projected = allocate<T>(scratch, s.count * kProjectedGradWidth);
    blend.grad_features = out.features;
    if (s.count > 0) {
      check_cuda(cudaMemsetAsync(blend.grad_projected, 0, sizeof(T) * s.count * kProjectedGradWidth, stream),
                 "gradient accumulator reset");
      check_cuda(cudaMemsetAsync(out.features, 0, sizeof(T) * s.count * s.channels, stream), "feature gradient reset");
    }
  }
  {
    const Stage stage("blend backward", stream);
    for_each_channel_chunk(s.channels, [&](auto width, int channel_begin, int channel_count) {
      blend_backward_kernel<T, decltype(width)::value>
          <<<unsigned(tiles), kBlendThreads, 0, stream>>>(blend, channel_begin, channel_count);
      check_cuda(cudaGetLastError(), "blend_backward_kernel launch");
    });
  }
  const Stage stage("project backward", stream);
  if (s.count > 0) {
    const ProjectBackwardParams<T> project{
        in, out, grid, deterministic, blend.grad_projected, blend.slots, blend.tile_limits};
    project_backward_kernel<T><<<blocks_for(s.count, kLinearThreads), kLinearThreads, 0, stream>>>(s, project);
    check_cuda(cudaGetLastError(), "project_backward_kernel launch");
  }
  background_grad_kernel<T><<<unsigned(s.channels), kLinearThreads, 0, stream>>>(blend.background_partials, tiles,
                                                                                 s.channels, out.background);
  check_cuda(cudaGetLastError(), "background_grad_kernel launch");
}

template void backward<float>(const SplatScene<float>&, const BackwardInputs<float>&, const Gradients<float>&, bool,
                              const ScratchAllocator&, cudaStream_t);
template void backward<double>(const SplatScene<double>&, const BackwardInputs<double>&, const Gradients<double>&, bool,
                               const ScratchAllocator&, cudaStream_t);

}  // namespace sfgs::splat::cuda_kernels
