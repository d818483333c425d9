// CUDA kernels of the splatting op; rasterize_kernels.h describes the pipeline. Every per-Gaussian and per-pair
// formula comes from splat/pair_math.h, which the CPU reference uses too.
#include "cuda/rasterize_kernels.h"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <type_traits>

#include <cub/device/device_radix_sort.cuh>
#include <cub/device/device_scan.cuh>

namespace sfgs::splat::cuda_kernels {
namespace {

constexpr int kWarpSize = 32;
constexpr unsigned kFullWarp = 0xffffffffu;
constexpr int kBlendThreads = kTileSize * kTileSize;  // one thread per pixel of a tile
constexpr int kBlendWarps = kBlendThreads / kWarpSize;
constexpr int kLinearThreads = 256;
// Feature channels handled per blend launch; wider features are blended in chunks of kMaxChunkChannels.
constexpr int kMaxChunkChannels = 4;
static_assert(kBlendThreads % kWarpSize == 0, "a tile must be whole warps");
static_assert(kBlendWarps * kWarpSize == kBlendThreads, "one backward bucket per warp and round");

StageObserver* g_stage_observer = nullptr;

void check_cuda(cudaError_t status, const char* what) {
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs CUDA backend: ") + what + " failed: " + cudaGetErrorString(status));
}

// Brackets one pipeline stage for an installed StageObserver.
class Stage {
 public:
  Stage(const char* name, cudaStream_t stream) : name_(name), stream_(stream) {
    if (g_stage_observer != nullptr) g_stage_observer->begin(name_, stream_);
  }
  ~Stage() {
    if (g_stage_observer != nullptr) g_stage_observer->end(name_, stream_);
  }
  Stage(const Stage&) = delete;
  Stage& operator=(const Stage&) = delete;

 private:
  const char* name_;
  cudaStream_t stream_;
};

template <typename U> U* allocate(const ScratchAllocator& scratch, int64_t count) {
  // A zero-byte request may return null, which CUB reads as "tell me the size": never ask for nothing.
  return static_cast<U*>(scratch(std::max<std::size_t>(1, std::size_t(count) * sizeof(U))));
}

unsigned blocks_for(int64_t count, int threads) {
  const int64_t blocks = (count + threads - 1) / threads;
  if (blocks > int64_t(INT32_MAX)) throw std::runtime_error("sfgs CUDA backend: launch of more than 2^31 - 1 blocks");
  return unsigned(blocks);
}

int bit_width(uint64_t v) {
  int bits = 0;
  for (; v != 0; v >>= 1) ++bits;
  return bits;
}

template <typename U> __host__ __device__ U smaller(U a, U b) { return a < b ? a : b; }

struct TileGrid {
  int width, height, tiles_x, tiles_y;
};

template <typename T> TileGrid make_grid(const PinholeCamera<T>& camera) {
  return TileGrid{camera.width, camera.height, (camera.width + kTileSize - 1) / kTileSize,
                  (camera.height + kTileSize - 1) / kTileSize};
}

__host__ __device__ int64_t tile_count(const TileGrid& grid) { return int64_t(grid.tiles_x) * grid.tiles_y; }

// Calls launch(std::integral_constant<int, K>, first channel, channel count) once per chunk of the features.
template <typename Launch> void for_each_channel_chunk(int channels, Launch&& launch) {
  switch (channels) {
    case 1: launch(std::integral_constant<int, 1>{}, 0, 1); return;
    case 2: launch(std::integral_constant<int, 2>{}, 0, 2); return;
    case 3: launch(std::integral_constant<int, 3>{}, 0, 3); return;
    default:
      for (int begin = 0; begin < channels; begin += kMaxChunkChannels)
        launch(std::integral_constant<int, kMaxChunkChannels>{}, begin, std::min(kMaxChunkChannels, channels - begin));
  }
}

// ---- per Gaussian ---------------------------------------------------------------------------------------------

template <typename T> struct DepthBits;
template <> struct DepthBits<float> {
  using Key = uint32_t;
  static constexpr int kBits = 31;  // depths are positive: the sign bit is always clear
  static __device__ Key of(float v) { return __float_as_uint(v); }
};
template <> struct DepthBits<double> {
  using Key = uint64_t;
  static constexpr int kBits = 63;
  static __device__ Key of(double v) { return Key(__double_as_longlong(v)); }
};
// Above every finite positive depth: culled Gaussians rank last.
template <typename T> constexpr typename DepthBits<T>::Key kCulledDepthKey =
    (typename DepthBits<T>::Key(1) << DepthBits<T>::kBits) - 1;

template <typename T> __device__ Mat3<T> world_covariance(const SplatScene<T>& s, int64_t i, bool& usable) {
  Mat3<T> cov(T(0));
  if (s.covariances != nullptr) {
    cov = unpack_covariance(s.covariances + 6 * i);
    usable = covariance_usable(cov);
  } else {
    const T* sc = s.scales + 3 * i;
    const T* q = s.rotations + 4 * i;
    usable = covariance_from_scale_rotation(Vec3<T>(sc[0], sc[1], sc[2]), Vec4<T>(q[0], q[1], q[2], q[3]), cov);
  }
  return cov;
}

template <typename T> __device__ Vec3<T> load_mean(const SplatScene<T>& s, int64_t i) {
  return Vec3<T>(s.means[3 * i], s.means[3 * i + 1], s.means[3 * i + 2]);
}

template <typename T> __device__ bool features_finite(const SplatScene<T>& s, int64_t i) {
  const T* f = s.features + i * s.channels;
  for (int c = 0; c < s.channels; ++c)
    if (!is_finite(f[c])) return false;
  return true;
}

template <typename T> __device__ ProjectedGaussian<T> load_projected(const T* p) {
  ProjectedGaussian<T> g;
  g.mean = Vec2<T>(p[kMeanX], p[kMeanY]);
  g.conic = Vec3<T>(p[kConicA], p[kConicB], p[kConicC]);
  g.opacity = p[kOpacity];
  g.depth = p[kDepth];
  g.level = p[kLevel];
  return g;
}

template <typename T> __device__ int32_t radius_pixels(T radius) {
  const T up = ceil_of(radius);
  return up >= T(INT32_MAX) ? INT32_MAX : int32_t(up);
}

template <typename T>
__global__ void project_kernel(const SplatScene<T> s, const ForwardBuffers<T> b, const TileGrid grid,
                               int64_t* tile_counts) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= s.count) return;
  int64_t touched = 0;
  TileRect rect{1, 1, 0, 0};
  int32_t radius_x = 0, radius_y = 0;
  bool usable = false;
  const Mat3<T> cov = world_covariance(s, i, usable);
  ProjectedGaussian<T> g;
  PixelRect pixels;
  Vec2<T> radius;
  if (usable && features_finite(s, i) &&
      project_gaussian(s.camera, s.projection, load_mean(s, i), cov, s.opacities[i], g, pixels, radius)) {
    const PixelRect t = tile_rect(pixels);
    for (int ty = t.y0; ty <= t.y1; ++ty)
      for (int tx = t.x0; tx <= t.x1; ++tx) touched += tile_touches(g, tx, ty, grid.width, grid.height);
    if (touched > 0) {
      T* p = b.projected + i * kProjectedWidth;
      p[kMeanX] = g.mean[0];
      p[kMeanY] = g.mean[1];
      p[kConicA] = g.conic[0];
      p[kConicB] = g.conic[1];
      p[kConicC] = g.conic[2];
      p[kOpacity] = g.opacity;
      p[kDepth] = g.depth;
      p[kLevel] = g.level;
      rect = TileRect{int16_t(t.x0), int16_t(t.y0), int16_t(t.x1), int16_t(t.y1)};
      radius_x = radius_pixels(radius[0]);
      radius_y = radius_pixels(radius[1]);
    }
  }
  tile_counts[i] = touched;
  b.tile_rects[i] = rect;
  b.radii[2 * i] = radius_x;
  b.radii[2 * i + 1] = radius_y;
}

__device__ bool rect_has_tiles(const TileRect& r) { return r.x0 <= r.x1 && r.y0 <= r.y1; }

template <typename T>
__global__ void depth_key_kernel(const T* projected, const TileRect* tile_rects, int64_t count,
                                 typename DepthBits<T>::Key* keys, int32_t* indices) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= count) return;
  keys[i] = rect_has_tiles(tile_rects[i]) ? DepthBits<T>::of(projected[i * kProjectedWidth + kDepth])
                                          : kCulledDepthKey<T>;
  indices[i] = int32_t(i);
}

__global__ void depth_rank_kernel(const int32_t* sorted, int64_t count, int32_t* depth_order, int32_t* depth_rank) {
  const int64_t r = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (r >= count) return;
  const int32_t gaussian = sorted[r];
  depth_order[r] = gaussian;
  depth_rank[gaussian] = int32_t(r);
}

// Gaussian-major emission: Gaussian i fills slots [offsets[i], offsets[i + 1]) in row-major tile order.
template <typename T, typename Key>
__global__ void emit_kernel(const ForwardBuffers<T> b, int64_t count, const TileGrid grid, int rank_bits,
                            Key* keys) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= count) return;
  int64_t slot = b.gaussian_offsets[i];
  const int64_t end = b.gaussian_offsets[i + 1];
  if (slot == end) return;
  const ProjectedGaussian<T> g = load_projected(b.projected + i * kProjectedWidth);
  const TileRect r = b.tile_rects[i];
  const Key rank = Key(b.depth_rank[i]);
  for (int ty = r.y0; ty <= r.y1; ++ty)
    for (int tx = r.x0; tx <= r.x1; ++tx)
      if (tile_touches(g, tx, ty, grid.width, grid.height)) {
        if (slot < end) keys[slot] = (Key(int64_t(ty) * grid.tiles_x + tx) << rank_bits) | rank;
        ++slot;
      }
  // The count and this pass evaluate the same test on the same values. Should they ever disagree, the slots stay
  // in bounds and the surplus carries the tile id one past the last, which sorts after every real tile.
  const Key past_last_tile = Key(tile_count(grid)) << rank_bits;
  for (; slot < end; ++slot) keys[slot] = past_last_tile;
}

template <typename Key>
__global__ void tile_ranges_kernel(const Key* keys, int64_t count, int rank_bits, int64_t tiles,
                                   const int32_t* depth_order, int32_t* isect_gaussian, int64_t* tile_offsets) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k >= count) return;
  const Key key = keys[k];
  const int64_t tile = int64_t(key >> rank_bits);
  const Key rank_mask = (Key(1) << rank_bits) - 1;
  isect_gaussian[k] = tile < tiles ? depth_order[key & rank_mask] : 0;
  const int64_t previous = k == 0 ? -1 : int64_t(keys[k - 1] >> rank_bits);
  const int64_t upto = smaller(tile, tiles);
  for (int64_t t = previous + 1; t <= upto; ++t) tile_offsets[t] = k;
  if (k == count - 1)
    for (int64_t t = upto + 1; t <= tiles; ++t) tile_offsets[t] = count;
}

// ---- forward blend --------------------------------------------------------------------------------------------

template <typename T, int kChannels> struct ForwardShared {
  T mean_x[kBlendThreads], mean_y[kBlendThreads];
  T conic_a[kBlendThreads], conic_b[kBlendThreads], conic_c[kBlendThreads];
  T opacity[kBlendThreads], depth[kBlendThreads];
  T features[kChannels][kBlendThreads];
};

// Stores Gaussian `gaussian` at batch position j of any of the shared layouts.
template <typename Shared, typename T>
__device__ void store_batch_gaussian(Shared& sh, int j, const T* projected, int32_t gaussian, const T* features,
                                     int channels, int channel_begin, int channel_count) {
  const T* p = projected + int64_t(gaussian) * kProjectedWidth;
  sh.mean_x[j] = p[kMeanX];
  sh.mean_y[j] = p[kMeanY];
  sh.conic_a[j] = p[kConicA];
  sh.conic_b[j] = p[kConicB];
  sh.conic_c[j] = p[kConicC];
  sh.opacity[j] = p[kOpacity];
  sh.depth[j] = p[kDepth];
  const T* f = features + int64_t(gaussian) * channels + channel_begin;
  constexpr int kChannels = std::extent<decltype(Shared::features)>::value;
#pragma unroll
  for (int c = 0; c < kChannels; ++c) sh.features[c][j] = c < channel_count ? f[c] : T(0);
}

template <typename Shared> __device__ auto batch_gaussian(const Shared& sh, int j) {
  using T = std::remove_cv_t<std::remove_reference_t<decltype(sh.mean_x[0])>>;
  ProjectedGaussian<T> g;
  g.mean = Vec2<T>(sh.mean_x[j], sh.mean_y[j]);
  g.conic = Vec3<T>(sh.conic_a[j], sh.conic_b[j], sh.conic_c[j]);
  g.opacity = sh.opacity[j];
  g.depth = sh.depth[j];
  g.level = T(0);  // only the tile test reads it
  return g;
}

template <typename T> struct BlendForwardParams {
  ForwardBuffers<T> b;
  const T* features;
  const T* background;
  int channels;
  TileGrid grid;
};

template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads)
    blend_forward_kernel(const BlendForwardParams<T> a, int channel_begin, int channel_count) {
  __shared__ ForwardShared<T, kChannels> sh;
  const int tile = blockIdx.x;
  const int x = (tile % a.grid.tiles_x) * kTileSize + int(threadIdx.x) % kTileSize;
  const int y = (tile / a.grid.tiles_x) * kTileSize + int(threadIdx.x) / kTileSize;
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
    for (int j = 0; !done && j < batch_size; ++j) {
      const ProjectedGaussian<T> g = batch_gaussian(sh, j);
      PairAlpha<T> pair;
      if (!pair_alpha(g, px, py, pair)) continue;
      const T next = transmittance * (T(1) - pair.alpha);
      if (next < T(kMinTransmittance)) {
        done = true;
        break;
      }
      const T weight = pair.alpha * transmittance;
#pragma unroll
      for (int c = 0; c < kChannels; ++c) colour[c] += weight * sh.features[c][j];
      depth += weight * g.depth;
      transmittance = next;
      last = int32_t(batch - begin + j + 1);
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
    a.b.final_transmittance[pix] = transmittance;
    a.b.contributors[pix] = last;
  }
}

// ---- backward blend -------------------------------------------------------------------------------------------

template <typename T> __device__ T warp_sum(T v) {
#pragma unroll
  for (int offset = kWarpSize / 2; offset > 0; offset /= 2) v += __shfl_xor_sync(kFullWarp, v, offset);
  return v;
}

// A tile's pixels are streamed through the warps in order of decreasing contributor count (stream position q), so
// that a bucket of Gaussians visits only the prefix of pixels that blended at least its first Gaussian.
template <typename T, int kChannels> struct BackwardShared {
  // Per stream position.
  T total_dot[kBlendThreads];  // image . grad_image over the chunk's channels
  T grad_depth[kBlendThreads], depth_sum[kBlendThreads], final_t[kBlendThreads], grad_alpha[kBlendThreads];
  T grad_colour[kChannels][kBlendThreads];
  int32_t last[kBlendThreads];   // contributors, non-increasing in q
  int32_t pixel[kBlendThreads];  // pixel (thread) index within the tile
  // Pixel state before the first Gaussian of each bucket of the round: transmittance, running dot, running depth.
  T checkpoint_t[kBlendWarps][kBlendThreads], checkpoint_dot[kBlendWarps][kBlendThreads],
      checkpoint_depth[kBlendWarps][kBlendThreads];
  // The round's Gaussians.
  T mean_x[kBlendThreads], mean_y[kBlendThreads];
  T conic_a[kBlendThreads], conic_b[kBlendThreads], conic_c[kBlendThreads];
  T opacity[kBlendThreads], depth[kBlendThreads];
  T features[kChannels][kBlendThreads];
  int32_t gaussian[kBlendThreads];
  // Per thread.
  int32_t last_by_thread[kBlendThreads];
  T warp_partial[kBlendWarps][kChannels];
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

template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads)
    blend_backward_kernel(const BlendBackwardParams<T> a, int channel_begin, int channel_count) {
  extern __shared__ __align__(16) unsigned char shared_bytes[];
  auto& sh = *reinterpret_cast<BackwardShared<T, kChannels>*>(shared_bytes);
  const int tid = threadIdx.x, warp = tid / kWarpSize, lane = tid % kWarpSize;
  const int tile = blockIdx.x;
  const int tile_x0 = (tile % a.grid.tiles_x) * kTileSize, tile_y0 = (tile / a.grid.tiles_x) * kTileSize;
  const int x = tile_x0 + tid % kTileSize, y = tile_y0 + tid / kTileSize;
  const bool inside = x < a.grid.width && y < a.grid.height;
  const int64_t pix = int64_t(y) * a.grid.width + x;
  const int64_t begin = a.in.tile_offsets[tile];
  const bool first_chunk = channel_begin == 0;
  const BackwardInputs<T>& in = a.in;

  // ---- this thread's pixel
  const int32_t last = inside ? in.contributors[pix] : 0;
  T grad_colour[kChannels];
  T total_dot = T(0);
#pragma unroll
  for (int c = 0; c < kChannels; ++c) {
    const bool used = inside && in.grad_image != nullptr && c < channel_count;
    grad_colour[c] = used ? in.grad_image[pix * a.channels + channel_begin + c] : T(0);
    if (used) total_dot += in.image[pix * a.channels + channel_begin + c] * grad_colour[c];
  }
  const T final_t = inside ? in.final_transmittance[pix] : T(0);
  const T grad_depth = inside && first_chunk && in.grad_depth_sum != nullptr ? in.grad_depth_sum[pix] : T(0);
  const T grad_alpha = inside && first_chunk && in.grad_alpha != nullptr ? in.grad_alpha[pix] : T(0);
  const T depth_sum = inside ? in.depth_sum[pix] : T(0);

  if (tid == 0) sh.max_last = 0;
  sh.last_by_thread[tid] = last;
#pragma unroll
  for (int c = 0; c < kChannels; ++c) {
    const T partial = warp_sum(final_t * grad_colour[c]);
    if (lane == 0) sh.warp_partial[warp][c] = partial;
  }
  __syncthreads();
  atomicMax(&sh.max_last, last);
  if (tid < channel_count) {
    T sum = T(0);
    for (int w = 0; w < kBlendWarps; ++w) sum += sh.warp_partial[w][tid];
    a.background_partials[int64_t(tile) * a.channels + channel_begin + tid] = sum;
  }
  // Stream position: contributor count descending, ties by pixel index.
  int rank = 0;
  for (int q = 0; q < kBlendThreads; ++q) {
    const int32_t other = sh.last_by_thread[q];
    rank += other > last || (other == last && q < tid);
  }
  sh.total_dot[rank] = total_dot;
  sh.grad_depth[rank] = grad_depth;
  sh.depth_sum[rank] = depth_sum;
  sh.final_t[rank] = final_t;
  sh.grad_alpha[rank] = grad_alpha;
#pragma unroll
  for (int c = 0; c < kChannels; ++c) sh.grad_colour[c][rank] = grad_colour[c];
  sh.last[rank] = last;
  sh.pixel[rank] = tid;
  __syncthreads();
  const int32_t limit = sh.max_last;
  if (first_chunk && tid == 0) a.tile_limits[tile] = limit;

  const T px = T(x) + T(kPixelCentre), py = T(y) + T(kPixelCentre);
  T transmittance = T(1), running_dot = T(0), running_depth = T(0);
  for (int32_t round = 0; round < limit; round += kBlendThreads) {
    const int round_size = int(smaller<int32_t>(kBlendThreads, limit - round));
    if (tid < round_size) {
      const int32_t gaussian = in.isect_gaussian[begin + round + tid];
      sh.gaussian[tid] = gaussian;
      store_batch_gaussian(sh, tid, in.projected, gaussian, a.features, a.channels, channel_begin, channel_count);
    }
    __syncthreads();

    // Replay this pixel front to back, as the forward pass did, recording its state at every bucket boundary.
    for (int bucket = 0; bucket < kBlendWarps; ++bucket) {
      sh.checkpoint_t[bucket][rank] = transmittance;
      sh.checkpoint_dot[bucket][rank] = running_dot;
      sh.checkpoint_depth[bucket][rank] = running_depth;
      const int bucket_end = smaller(round_size, (bucket + 1) * kWarpSize);
      for (int j = bucket * kWarpSize; j < bucket_end && round + j < last; ++j) {
        const ProjectedGaussian<T> g = batch_gaussian(sh, j);
        PairAlpha<T> pair;
        if (!pair_alpha(g, px, py, pair)) continue;
        const T weight = pair.alpha * transmittance;
        T dot = T(0);
#pragma unroll
        for (int c = 0; c < kChannels; ++c) dot += sh.features[c][j] * grad_colour[c];
        running_dot += weight * dot;
        running_depth += weight * g.depth;
        transmittance *= T(1) - pair.alpha;
      }
    }
    __syncthreads();

    // Each warp takes one bucket of 32 Gaussians, one per lane. Stream pixel q reaches lane l at step q + l and
    // carries the pixel's state from lane l - 1, so every lane sees its pixels' exact front-to-back state.
    const int32_t bucket_begin = round + warp * kWarpSize;
    if (bucket_begin < limit) {
      int active = 0, upper = kBlendThreads;  // pixels that blended the bucket's first Gaussian: a prefix
      while (active < upper) {
        const int mid = (active + upper) / 2;
        if (sh.last[mid] > bucket_begin) active = mid + 1;
        else upper = mid;
      }
      const int j = warp * kWarpSize + lane;
      const bool has_gaussian = j < round_size;
      ProjectedGaussian<T> g = batch_gaussian(sh, has_gaussian ? j : 0);
      T features[kChannels];
#pragma unroll
      for (int c = 0; c < kChannels; ++c) features[c] = sh.features[c][has_gaussian ? j : 0];
      const int32_t local_index = round + j;

      Vec2<T> grad_mean(T(0));
      Vec3<T> grad_conic(T(0));
      T grad_opacity = T(0), grad_depth_total = T(0);
      T grad_features[kChannels];
#pragma unroll
      for (int c = 0; c < kChannels; ++c) grad_features[c] = T(0);
      bool contributed = false;

      T state_t = T(0), state_dot = T(0), state_depth = T(0);
      for (int step = 0; step < active + kWarpSize - 1; ++step) {
        state_t = __shfl_up_sync(kFullWarp, state_t, 1);
        state_dot = __shfl_up_sync(kFullWarp, state_dot, 1);
        state_depth = __shfl_up_sync(kFullWarp, state_depth, 1);
        if (lane == 0 && step < active) {
          state_t = sh.checkpoint_t[warp][step];
          state_dot = sh.checkpoint_dot[warp][step];
          state_depth = sh.checkpoint_depth[warp][step];
        }
        const int q = step - lane;
        if (!has_gaussian || q < 0 || q >= active || local_index >= sh.last[q]) continue;
        const int p = sh.pixel[q];
        PairAlpha<T> pair;
        if (!pair_alpha(g, T(tile_x0 + p % kTileSize) + T(kPixelCentre),
                        T(tile_y0 + p / kTileSize) + T(kPixelCentre), pair))
          continue;
        const T weight = pair.alpha * state_t;
        T dot = T(0);
#pragma unroll
        for (int c = 0; c < kChannels; ++c) {
          const T gc = sh.grad_colour[c][q];
          dot += features[c] * gc;
          grad_features[c] += weight * gc;
        }
        state_dot += weight * dot;
        state_depth += weight * g.depth;
        const T pixel_grad_depth = sh.grad_depth[q];
        grad_depth_total += weight * pixel_grad_depth;
        const T grad_pair_alpha =
            composite_grad_alpha(pair.alpha, state_t, dot, sh.total_dot[q] - state_dot, g.depth, pixel_grad_depth,
                                 sh.depth_sum[q] - state_depth, sh.final_t[q], sh.grad_alpha[q]);
        pair_alpha_vjp(g, pair, grad_pair_alpha, grad_mean, grad_conic, grad_opacity);
        state_t *= T(1) - pair.alpha;
        contributed = true;
      }

      const T geometric[kProjectedGradWidth] = {grad_mean[0],  grad_mean[1], grad_conic[0],   grad_conic[1],
                                                grad_conic[2], grad_opacity, grad_depth_total};
      if (a.deterministic && has_gaussian) {
        T* slot = a.slots + (begin + local_index) * (kProjectedGradWidth + a.channels);
#pragma unroll
        for (int f = 0; f < kProjectedGradWidth; ++f) slot[f] = first_chunk ? geometric[f] : slot[f] + geometric[f];
#pragma unroll
        for (int c = 0; c < kChannels; ++c)
          if (c < channel_count) slot[kProjectedGradWidth + channel_begin + c] = grad_features[c];
      } else if (!a.deterministic && contributed) {
        const int64_t gaussian = sh.gaussian[j];
        T* grad = a.grad_projected + gaussian * kProjectedGradWidth;
#pragma unroll
        for (int f = 0; f < kProjectedGradWidth; ++f) atomicAdd(grad + f, geometric[f]);
        T* grad_f = a.grad_features + gaussian * a.channels + channel_begin;
#pragma unroll
        for (int c = 0; c < kChannels; ++c)
          if (c < channel_count) atomicAdd(grad_f + c, grad_features[c]);
      }
    }
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

// Position of the Gaussian of depth rank `rank` among a tile's blended intersections, -1 if absent. Within a tile
// the intersections are sorted by rank.
template <typename T>
__device__ int64_t find_intersection(const ProjectBackwardParams<T>& a, int64_t tile, int32_t rank) {
  int64_t lo = a.in.tile_offsets[tile], hi = lo + a.tile_limits[tile];
  while (lo < hi) {
    const int64_t mid = lo + (hi - lo) / 2;
    const int32_t mid_rank = a.in.depth_rank[a.in.isect_gaussian[mid]];
    if (mid_rank == rank) return mid;
    if (mid_rank < rank) lo = mid + 1;
    else hi = mid;
  }
  return -1;
}

template <typename T>
__global__ void project_backward_kernel(const SplatScene<T> s, const ProjectBackwardParams<T> a) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= s.count) return;
  const Gradients<T>& out = a.out;
  const TileRect r = a.in.tile_rects[i];
  const bool visible = rect_has_tiles(r);
  T grad[kProjectedGradWidth];
#pragma unroll
  for (int f = 0; f < kProjectedGradWidth; ++f) grad[f] = T(0);
  if (a.deterministic) {
    T* grad_features = out.features + i * s.channels;
    for (int c = 0; c < s.channels; ++c) grad_features[c] = T(0);
    const int32_t rank = visible ? a.in.depth_rank[i] : 0;
    for (int ty = r.y0; visible && ty <= r.y1; ++ty)
      for (int tx = r.x0; tx <= r.x1; ++tx) {
        const int64_t k = find_intersection(a, int64_t(ty) * a.grid.tiles_x + tx, rank);
        if (k < 0) continue;
        const T* slot = a.slots + k * (kProjectedGradWidth + s.channels);
#pragma unroll
        for (int f = 0; f < kProjectedGradWidth; ++f) grad[f] += slot[f];
        for (int c = 0; c < s.channels; ++c) grad_features[c] += slot[kProjectedGradWidth + c];
      }
  } else if (visible) {
#pragma unroll
    for (int f = 0; f < kProjectedGradWidth; ++f) grad[f] = a.grad_projected[i * kProjectedGradWidth + f];
  }

  Vec3<T> grad_mean(T(0));
  Mat3<T> grad_cov(T(0));
  T grad_opacity = T(0);
  bool usable = false;
  const Mat3<T> cov = world_covariance(s, i, usable);
  if (visible)
    project_gaussian_vjp(s.camera, s.projection, load_mean(s, i), cov, s.opacities[i],
                         Vec2<T>(grad[kGradMeanX], grad[kGradMeanY]),
                         Vec3<T>(grad[kGradConicA], grad[kGradConicB], grad[kGradConicC]), grad[kGradOpacity],
                         grad[kGradDepth], grad_mean, grad_cov, grad_opacity);
  for (int k = 0; k < 3; ++k) out.means[3 * i + k] = grad_mean[k];
  out.opacities[i] = grad_opacity;
  if (s.covariances != nullptr) {
    pack_covariance_gradient(grad_cov, out.covariances + 6 * i);
    return;
  }
  Vec3<T> grad_scale(T(0));
  Vec4<T> grad_quaternion(T(0));
  if (visible) {
    const T* sc = s.scales + 3 * i;
    const T* q = s.rotations + 4 * i;
    covariance_from_scale_rotation_vjp(Vec3<T>(sc[0], sc[1], sc[2]), Vec4<T>(q[0], q[1], q[2], q[3]), grad_cov,
                                       grad_scale, grad_quaternion);
  }
  for (int k = 0; k < 3; ++k) out.scales[3 * i + k] = grad_scale[k];
  for (int k = 0; k < 4; ++k) out.rotations[4 * i + k] = grad_quaternion[k];
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

// ---- host side --------------------------------------------------------------------------------------------------

template <typename T> BlendForwardParams<T> forward_params(const SplatScene<T>& s, const ForwardBuffers<T>& b) {
  return BlendForwardParams<T>{b, s.features, s.background, s.channels, make_grid(s.camera)};
}

template <typename T> void launch_blend_forward(const SplatScene<T>& s, const ForwardBuffers<T>& b,
                                                cudaStream_t stream) {
  const BlendForwardParams<T> params = forward_params(s, b);
  const unsigned tiles = unsigned(tile_count(params.grid));
  for_each_channel_chunk(s.channels, [&](auto width, int channel_begin, int channel_count) {
    blend_forward_kernel<T, decltype(width)::value>
        <<<tiles, kBlendThreads, 0, stream>>>(params, channel_begin, channel_count);
    check_cuda(cudaGetLastError(), "blend_forward_kernel launch");
  });
}

template <typename T, typename Key>
void bin(const SplatScene<T>& s, const ForwardBuffers<T>& b, int64_t intersections, int rank_bits, int key_bits,
         const ScratchAllocator& scratch, cudaStream_t stream) {
  const TileGrid grid = make_grid(s.camera);
  cub::DoubleBuffer<Key> keys(allocate<Key>(scratch, intersections), allocate<Key>(scratch, intersections));
  {
    const Stage stage("emit", stream);
    emit_kernel<T, Key><<<blocks_for(s.count, kLinearThreads), kLinearThreads, 0, stream>>>(b, s.count, grid,
                                                                                            rank_bits, keys.Current());
    check_cuda(cudaGetLastError(), "emit_kernel launch");
  }
  {
    const Stage stage("tile sort", stream);
    std::size_t temp_bytes = 0;
    check_cuda(cub::DeviceRadixSort::SortKeys(nullptr, temp_bytes, keys, intersections, 0, key_bits, stream),
               "tile sort size query");
    void* temp = allocate<unsigned char>(scratch, int64_t(temp_bytes));
    check_cuda(cub::DeviceRadixSort::SortKeys(temp, temp_bytes, keys, intersections, 0, key_bits, stream),
               "tile sort");
  }
  {
    const Stage stage("tile ranges", stream);
    tile_ranges_kernel<Key><<<blocks_for(intersections, kLinearThreads), kLinearThreads, 0, stream>>>(
        keys.Current(), intersections, rank_bits, tile_count(grid), b.depth_order, b.isect_gaussian,
        b.tile_offsets);
    check_cuda(cudaGetLastError(), "tile_ranges_kernel launch");
  }
}

}  // namespace

void set_stage_observer(StageObserver* observer) { g_stage_observer = observer; }

template <typename T>
void project_gaussians(const SplatScene<T>& s, const ForwardBuffers<T>& b, const ScratchAllocator& scratch,
                       cudaStream_t stream) {
  const Stage stage("project", stream);
  check_cuda(cudaMemsetAsync(b.gaussian_offsets, 0, sizeof(int64_t), stream), "offset reset");
  if (s.count == 0) return;
  int64_t* tile_counts = allocate<int64_t>(scratch, s.count);
  project_kernel<T><<<blocks_for(s.count, kLinearThreads), kLinearThreads, 0, stream>>>(s, b, make_grid(s.camera),
                                                                                         tile_counts);
  check_cuda(cudaGetLastError(), "project_kernel launch");
  std::size_t temp_bytes = 0;
  check_cuda(cub::DeviceScan::InclusiveSum(nullptr, temp_bytes, tile_counts, b.gaussian_offsets + 1, s.count, stream),
             "tile count scan size query");
  void* temp = allocate<unsigned char>(scratch, int64_t(temp_bytes));
  check_cuda(cub::DeviceScan::InclusiveSum(temp, temp_bytes, tile_counts, b.gaussian_offsets + 1, s.count, stream),
             "tile count scan");
}

template <typename T>
void sort_by_depth(const SplatScene<T>& s, const ForwardBuffers<T>& b, const ScratchAllocator& scratch,
                   cudaStream_t stream) {
  if (s.count == 0) return;
  const Stage stage("depth sort", stream);
  using Key = typename DepthBits<T>::Key;
  cub::DoubleBuffer<Key> keys(allocate<Key>(scratch, s.count), allocate<Key>(scratch, s.count));
  cub::DoubleBuffer<int32_t> indices(allocate<int32_t>(scratch, s.count), b.depth_order);
  const unsigned blocks = blocks_for(s.count, kLinearThreads);
  depth_key_kernel<T><<<blocks, kLinearThreads, 0, stream>>>(b.projected, b.tile_rects, s.count, keys.Current(),
                                                            indices.Current());
  check_cuda(cudaGetLastError(), "depth_key_kernel launch");
  // Radix sort is stable: equal depths keep index order, as the CPU reference's stable sort does.
  std::size_t temp_bytes = 0;
  check_cuda(cub::DeviceRadixSort::SortPairs(nullptr, temp_bytes, keys, indices, s.count, 0, DepthBits<T>::kBits,
                                             stream),
             "depth sort size query");
  void* temp = allocate<unsigned char>(scratch, int64_t(temp_bytes));
  check_cuda(cub::DeviceRadixSort::SortPairs(temp, temp_bytes, keys, indices, s.count, 0, DepthBits<T>::kBits, stream),
             "depth sort");
  depth_rank_kernel<<<blocks, kLinearThreads, 0, stream>>>(indices.Current(), s.count, b.depth_order, b.depth_rank);
  check_cuda(cudaGetLastError(), "depth_rank_kernel launch");
}

template <typename T>
void bin_and_blend(const SplatScene<T>& s, const ForwardBuffers<T>& b, int64_t intersections,
                   const ScratchAllocator& scratch, cudaStream_t stream) {
  const TileGrid grid = make_grid(s.camera);
  if (intersections > 0) {
    // Ranks need bit_width(N - 1) bits; tile ids up to and including the one-past-the-last sentinel.
    const int rank_bits = std::max(1, bit_width(uint64_t(s.count - 1)));
    const int key_bits = rank_bits + bit_width(uint64_t(tile_count(grid)));
    if (key_bits <= 32)
      bin<T, uint32_t>(s, b, intersections, rank_bits, key_bits, scratch, stream);
    else
      bin<T, uint64_t>(s, b, intersections, rank_bits, key_bits, scratch, stream);
  } else {
    check_cuda(cudaMemsetAsync(b.tile_offsets, 0, sizeof(int64_t) * (tile_count(grid) + 1), stream),
               "tile offset reset");
  }
  const Stage stage("blend", stream);
  launch_blend_forward(s, b, stream);
}

template <typename T>
void backward(const SplatScene<T>& s, const BackwardInputs<T>& in, const Gradients<T>& out, bool deterministic,
              const ScratchAllocator& scratch, cudaStream_t stream) {
  const TileGrid grid = make_grid(s.camera);
  const int64_t tiles = tile_count(grid);
  BlendBackwardParams<T> blend{in, s.features, s.channels, grid, deterministic, nullptr, nullptr, nullptr, nullptr,
                               nullptr};
  blend.tile_limits = allocate<int32_t>(scratch, tiles);
  blend.background_partials = allocate<T>(scratch, tiles * s.channels);
  if (deterministic) {
    blend.slots = allocate<T>(scratch, in.intersection_count * (kProjectedGradWidth + s.channels));
  } else {
    blend.grad_projected = allocate<T>(scratch, s.count * kProjectedGradWidth);
    blend.grad_features = out.features;
    check_cuda(cudaMemsetAsync(blend.grad_projected, 0, sizeof(T) * s.count * kProjectedGradWidth, stream),
               "gradient accumulator reset");
    check_cuda(cudaMemsetAsync(out.features, 0, sizeof(T) * s.count * s.channels, stream), "feature gradient reset");
  }
  {
    const Stage stage("blend backward", stream);
    for_each_channel_chunk(s.channels, [&](auto width, int channel_begin, int channel_count) {
      constexpr int kChannels = decltype(width)::value;
      const int shared_bytes = int(sizeof(BackwardShared<T, kChannels>));
      check_cuda(cudaFuncSetAttribute(blend_backward_kernel<T, kChannels>,
                                      cudaFuncAttributeMaxDynamicSharedMemorySize, shared_bytes),
                 "blend_backward_kernel shared memory opt-in");
      blend_backward_kernel<T, kChannels>
          <<<unsigned(tiles), kBlendThreads, shared_bytes, stream>>>(blend, channel_begin, channel_count);
      check_cuda(cudaGetLastError(), "blend_backward_kernel launch");
    });
  }
  const Stage stage("project backward", stream);
  if (s.count > 0) {
    const ProjectBackwardParams<T> project{in,          out,        grid, deterministic, blend.grad_projected,
                                           blend.slots, blend.tile_limits};
    project_backward_kernel<T><<<blocks_for(s.count, kLinearThreads), kLinearThreads, 0, stream>>>(s, project);
    check_cuda(cudaGetLastError(), "project_backward_kernel launch");
  }
  background_grad_kernel<T><<<unsigned(s.channels), kLinearThreads, 0, stream>>>(blend.background_partials, tiles,
                                                                                  s.channels, out.background);
  check_cuda(cudaGetLastError(), "background_grad_kernel launch");
}

#define SFGS_INSTANTIATE(T)                                                                                         \
  template void project_gaussians<T>(const SplatScene<T>&, const ForwardBuffers<T>&, const ScratchAllocator&,      \
                                     cudaStream_t);                                                                 \
  template void sort_by_depth<T>(const SplatScene<T>&, const ForwardBuffers<T>&, const ScratchAllocator&,          \
                                 cudaStream_t);                                                                     \
  template void bin_and_blend<T>(const SplatScene<T>&, const ForwardBuffers<T>&, int64_t, const ScratchAllocator&, \
                                 cudaStream_t);                                                                     \
  template void backward<T>(const SplatScene<T>&, const BackwardInputs<T>&, const Gradients<T>&, bool,             \
                            const ScratchAllocator&, cudaStream_t);
SFGS_INSTANTIATE(float)
SFGS_INSTANTIATE(double)
#undef SFGS_INSTANTIATE

}  // namespace sfgs::splat::cuda_kernels
