// CUDA kernels of the splatting op; rasterize_kernels.h describes the pipeline. Every per-Gaussian and per-pair
// formula comes from splat/pair_math.h, which the CPU reference uses too.
#include "cuda/rasterize_kernels.h"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <type_traits>

#include <cub/block/block_radix_sort.cuh>
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
// Each warp of a tile covers a compact 8 x 4 block of pixels, so that a Gaussian tends to cover all or none of a
// warp's pixels and the warp can skip it with one vote.
constexpr int kWarpBlockWidth = 8;
constexpr int kWarpBlockHeight = kWarpSize / kWarpBlockWidth;
constexpr int kWarpBlocksPerRow = kTileSize / kWarpBlockWidth;
// Gaussians per backward batch (one ballot covers a batch), and per-Gaussian gradient values after the warp
// reduction (a power of two).
constexpr int kBackwardBatch = kWarpSize;
constexpr int kReducedValues = 16;
// Resident blend blocks per multiprocessor that the float kernels are register-limited for (40 and 48 registers,
// no spills); double keeps the compiler's choice.
template <typename T> constexpr int kForwardBlendBlocks = std::is_same_v<T, float> ? 6 : 1;
template <typename T> constexpr int kBackwardBlendBlocks = std::is_same_v<T, float> ? 5 : 1;
// Tile rectangles of at most this many tiles keep their touched tiles as a bit mask, so that emission reads the
// tile test's results instead of evaluating it again.
constexpr int kMaskedRectTiles = 64;
// Each tile's intersections are counted and emitted through kTileBuckets counters (Gaussian i uses counter
// i % kTileBuckets, its lane), so that a tile's atomics spread over as many addresses; the tile's run is the
// concatenation of its buckets.
constexpr int kTileBuckets = kWarpSize;
// Threads of the per-tile sort and of the one-block tile finalisation; radix digit width of the per-tile sort (at a
// few keys per thread, the digit counters' shared-memory traffic grows faster with the width than passes shrink).
constexpr int kSortThreads = 256;
constexpr int kSortRadixBits = 4;
// Emission issues the atomics of up to this many tiles before it uses their results.
constexpr int kEmitBatch = 8;
constexpr int kFinalizeThreads = 1024;
// Tiles are blended longest first: classes by bit width of the run length, then the empty tiles.
constexpr int kLengthClasses = 33;
static_assert(kBlendThreads % kWarpSize == 0, "a tile must be whole warps");
static_assert(kTileSize % kWarpBlockWidth == 0 && kTileSize % kWarpBlockHeight == 0, "warp blocks must tile a tile");

StageObserver* g_stage_observer = nullptr;
Binning g_binning = Binning::kAuto;
Binning g_last_binning = Binning::kAuto;
TileOrder g_tile_order = TileOrder::kLongestFirst;

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

// One intersection as emitted for the per-tile sort: its Gaussian's depth bits (depths are positive and finite, so
// the bits order as the values) and index. A record of all one bits is a slot emission never wrote (only possible
// were the tile test ever to disagree with project_kernel's count); it sorts last and names Gaussian -1.
template <typename T> struct TileRecord;
template <> struct TileRecord<float> {
  using Type = unsigned long long;  // depth bits << 32 | Gaussian
  using Depth = uint32_t;
  static constexpr int kCapacity = 4096;  // longest run sorted in shared memory: 16 per thread
  static __device__ Type make(float depth, int32_t gaussian) {
    return (Type(__float_as_uint(depth)) << 32) | uint32_t(gaussian);
  }
  static __device__ bool unwritten(const Type& r) { return r == ~Type(0); }
  static __device__ Depth depth(const Type& r) { return Depth(r >> 32); }
  static __device__ int32_t gaussian(const Type& r) { return int32_t(uint32_t(r)); }
};
struct DoubleTileRecord {
  unsigned long long depth;
  int32_t gaussian, unused;
};
template <> struct TileRecord<double> {
  using Type = DoubleTileRecord;
  using Depth = unsigned long long;
  static constexpr int kCapacity = 2048;  // 64-bit depth keys: 8 per thread in about the same shared memory
  static __device__ Type make(double depth, int32_t gaussian) {
    return Type{static_cast<unsigned long long>(__double_as_longlong(depth)), gaussian, 0};
  }
  static __device__ bool unwritten(const Type& r) { return r.depth == ~Depth(0); }
  static __device__ Depth depth(const Type& r) { return r.depth; }
  static __device__ int32_t gaussian(const Type& r) { return r.gaussian; }
};

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


__device__ bool rect_has_tiles(const TileRect& r) { return r.x0 <= r.x1 && r.y0 <= r.y1; }

__device__ int64_t rect_tiles(const TileRect& r) { return int64_t(r.x1 - r.x0 + 1) * (r.y1 - r.y0 + 1); }

// Calls visit(tile id) for every tile Gaussian `gaussian` touches: from its bit mask when its rectangle has at most
// kMaskedRectTiles tiles (the very results project_kernel counted), else by evaluating the tile test again.
template <typename T, typename Visit>
__device__ void for_each_touched_tile(const ForwardBuffers<T>& b, int64_t gaussian, const TileRect& r,
                                      const TileGrid& grid, Visit&& visit) {
  const int width = r.x1 - r.x0 + 1;
  if (rect_tiles(r) <= kMaskedRectTiles) {
    for (uint64_t m = b.touched_masks[gaussian]; m != 0; m &= m - 1) {
      const int k = __ffsll(static_cast<long long>(m)) - 1;
      visit(int64_t(r.y0 + k / width) * grid.tiles_x + r.x0 + k % width);
    }
    return;
  }
  const ProjectedGaussian<T> g = load_projected(b.projected + gaussian * kProjectedWidth);
  for (int ty = r.y0; ty <= r.y1; ++ty)
    for (int tx = r.x0; tx <= r.x1; ++tx)
      if (tile_touches(g, tx, ty, grid.width, grid.height)) visit(int64_t(ty) * grid.tiles_x + tx);
}

template <typename T>
__global__ void project_kernel(const SplatScene<T> s, const ForwardBuffers<T> b, const TileGrid grid) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= s.count) return;
  int64_t touched = 0;
  uint64_t mask = 0;
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
    const int width = t.x1 - t.x0 + 1;
    const bool masked = int64_t(width) * (t.y1 - t.y0 + 1) <= kMaskedRectTiles;
    for (int ty = t.y0; ty <= t.y1; ++ty)
      for (int tx = t.x0; tx <= t.x1; ++tx)
        if (tile_touches(g, tx, ty, grid.width, grid.height)) {
          ++touched;
          atomicAdd(b.bucket_counts + (int64_t(ty) * grid.tiles_x + tx) * kTileBuckets + i % kTileBuckets, 1ull);
          if (masked) mask |= uint64_t(1) << ((ty - t.y0) * width + (tx - t.x0));
        }
    if (touched > 0) {
      store_projected(g, b.projected + i * kProjectedWidth);
      rect = TileRect{int16_t(t.x0), int16_t(t.y0), int16_t(t.x1), int16_t(t.y1)};
      radius_x = pixel_radius(radius[0]);
      radius_y = pixel_radius(radius[1]);
    }
  }
  b.gaussian_tile_counts[i] = touched;
  b.touched_masks[i] = mask;
  b.tile_rects[i] = rect;
  b.radii[2 * i] = radius_x;
  b.radii[2 * i + 1] = radius_y;
}

// Blend order class of a tile's run: longer runs (by bit width) first, the empty tiles last.
__device__ int length_class(int64_t length) {
  if (length == 0) return kLengthClasses - 1;
  const int width = 64 - __clzll(length);
  return width >= kLengthClasses - 1 ? 0 : kLengthClasses - 1 - width;
}

// Adds `amount` to counter c of `counters` for every calling lane, one shared atomic per distinct c in the warp;
// returns this lane's start. All lanes of the warp must call it (lanes with c < 0 take part without counting).
__device__ unsigned warp_aggregated_add(unsigned* counters, int c, unsigned amount) {
  const unsigned peers = __match_any_sync(kFullWarp, c);
  const int lane = threadIdx.x % kWarpSize, leader = __ffs(peers) - 1;
  const unsigned before = __popc(peers & ((1u << lane) - 1u));
  unsigned base = 0;
  if (lane == leader && c >= 0) base = atomicAdd(counters + c, amount * __popc(peers));
  base = __shfl_sync(kFullWarp, base, leader);
  return base + before * amount;
}

// One block, after the exclusive scan of the bucket counts: each tile's offset (tiles + 1 entries, the last the
// intersection count), BinStats, and the tile order of the blends (longest runs first, the empty tiles last, or
// row-major).
__global__ void __launch_bounds__(kFinalizeThreads)
    finalize_tiles_kernel(const int64_t* bucket_offsets, int64_t tiles, int64_t* tile_offsets, int32_t* tile_order,
                          BinStats* stats, bool row_major) {
  __shared__ unsigned class_start[kLengthClasses];
  __shared__ unsigned warp_longest[kFinalizeThreads / kWarpSize];
  const int tid = threadIdx.x;
  if (tid < kLengthClasses) class_start[tid] = 0;
  __syncthreads();
  unsigned longest = 0;
  // Whole warps take every step, so that the aggregated atomics see all lanes.
  for (int64_t base = 0; base < tiles; base += kFinalizeThreads) {
    const int64_t t = base + tid;
    int c = -1;
    if (t < tiles) {
      const int64_t begin = bucket_offsets[t * kTileBuckets];
      const int64_t length = bucket_offsets[(t + 1) * kTileBuckets] - begin;
      tile_offsets[t] = begin;
      longest = unsigned(length) > longest ? unsigned(length) : longest;
      c = length_class(length);
    }
    warp_aggregated_add(class_start, c, 1u);
  }
  longest = __reduce_max_sync(kFullWarp, longest);
  if (tid % kWarpSize == 0) warp_longest[tid / kWarpSize] = longest;
  __syncthreads();
  if (tid == 0) {
    unsigned start = 0;
    for (int c = 0; c < kLengthClasses; ++c) {
      const unsigned count = class_start[c];
      class_start[c] = start;
      start += count;
    }
    for (int w = 0; w < kFinalizeThreads / kWarpSize; ++w) longest = warp_longest[w] > longest ? warp_longest[w] : longest;
    const int64_t total = bucket_offsets[tiles * kTileBuckets];
    tile_offsets[tiles] = total;
    *stats = BinStats{total, int64_t(longest)};
  }
  __syncthreads();
  for (int64_t base = 0; base < tiles; base += kFinalizeThreads) {
    const int64_t t = base + tid;
    const int c =
        t < tiles ? length_class(bucket_offsets[(t + 1) * kTileBuckets] - bucket_offsets[t * kTileBuckets]) : -1;
    const unsigned position = warp_aggregated_add(class_start, row_major ? -1 : c, 1u);
    if (t < tiles) tile_order[row_major ? t : position] = int32_t(t);
  }
}

// Per-tile path: Gaussian i writes its record into the next free slot of its bucket of each touched tile's run.
// From a bit mask, the atomics of up to kEmitBatch tiles are issued before their results are used, so that their
// round trips overlap. A cursor past the bucket (only if the tile test ever disagreed with project_kernel's) drops
// the write.
template <typename T>
__global__ void emit_tile_records_kernel(const ForwardBuffers<T> b, int64_t count, const TileGrid grid,
                                         unsigned* cursors, typename TileRecord<T>::Type* records) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= count) return;
  const TileRect r = b.tile_rects[i];
  if (!rect_has_tiles(r)) return;
  const auto record = TileRecord<T>::make(b.projected[i * kProjectedWidth + kDepth], int32_t(i));
  const int64_t bucket_in_tile = i % kTileBuckets;
  const auto store = [&](int64_t bucket, unsigned slot) {
    const int64_t begin = b.bucket_offsets[bucket], size = b.bucket_offsets[bucket + 1] - begin;
    if (int64_t(slot) < size) records[begin + int64_t(slot)] = record;
  };
  if (rect_tiles(r) > kMaskedRectTiles) {
    for_each_touched_tile(b, i, r, grid, [&](int64_t tile) {
      const int64_t bucket = tile * kTileBuckets + bucket_in_tile;
      store(bucket, atomicAdd(cursors + bucket, 1u));
    });
    return;
  }
  const int width = r.x1 - r.x0 + 1;
  for (uint64_t m = b.touched_masks[i]; m != 0;) {
    int64_t bucket[kEmitBatch];
    unsigned slot[kEmitBatch];
#pragma unroll
    for (int k = 0; k < kEmitBatch; ++k) {
      bucket[k] = -1;
      slot[k] = 0;
      if (m != 0) {
        const int bit = __ffsll(static_cast<long long>(m)) - 1;
        m &= m - 1;
        bucket[k] = (int64_t(r.y0 + bit / width) * grid.tiles_x + r.x0 + bit % width) * kTileBuckets + bucket_in_tile;
        slot[k] = atomicAdd(cursors + bucket[k], 1u);
      }
    }
#pragma unroll
    for (int k = 0; k < kEmitBatch; ++k)
      if (bucket[k] >= 0) store(bucket[k], slot[k]);
  }
}

template <typename T, int kItems>
using DepthSort = cub::BlockRadixSort<typename TileRecord<T>::Depth, kSortThreads, kItems, int32_t, kSortRadixBits>;
template <typename T, int kItems>
using IndexSort = cub::BlockRadixSort<uint32_t, kSortThreads, kItems, typename TileRecord<T>::Depth, kSortRadixBits>;
template <typename T> constexpr int kMaxSortItems = TileRecord<T>::kCapacity / kSortThreads;
template <typename T, int kMaxItems>
constexpr std::size_t kSortStorageBytes = sizeof(typename DepthSort<T, kMaxItems>::TempStorage) >
                                                  sizeof(typename IndexSort<T, kMaxItems>::TempStorage)
                                              ? sizeof(typename DepthSort<T, kMaxItems>::TempStorage)
                                              : sizeof(typename IndexSort<T, kMaxItems>::TempStorage);

template <typename T, int kMaxItems> struct SortShared {
  alignas(16) unsigned char storage[kSortStorageBytes<T, kMaxItems>];
  typename TileRecord<T>::Depth first_key[kSortThreads];
  typename TileRecord<T>::Depth warp_min[kSortThreads / kWarpSize], warp_max[kSortThreads / kWarpSize];
};

template <typename U> __device__ U warp_min_of(U v) {
#pragma unroll
  for (int offset = kWarpSize / 2; offset > 0; offset /= 2) {
    const U other = __shfl_xor_sync(kFullWarp, v, offset);
    v = other < v ? other : v;
  }
  return v;
}
template <typename U> __device__ U warp_max_of(U v) {
#pragma unroll
  for (int offset = kWarpSize / 2; offset > 0; offset /= 2) {
    const U other = __shfl_xor_sync(kFullWarp, v, offset);
    v = other > v ? other : v;
  }
  return v;
}

// Sorts one tile's run of at most kItems * kSortThreads records in shared memory and writes its Gaussians in
// (depth, index) order: a radix sort of the depth bits relative to the tile's nearest (as few bits as the tile's
// depth range needs), carrying the index; where two depths are equal, the run is sorted by index first and then
// again, stably, by depth.
template <typename T, int kItems, typename Shared>
__device__ void sort_tile_run(Shared& sh, const typename TileRecord<T>::Type* records, int64_t begin, int length,
                              int32_t* isect_gaussian) {
  using Record = TileRecord<T>;
  using Depth = typename Record::Depth;
  using Sort = DepthSort<T, kItems>;
  using ByIndex = IndexSort<T, kItems>;
  static_assert(sizeof(typename Sort::TempStorage) <= sizeof(sh.storage), "sort storage too small");
  static_assert(sizeof(typename ByIndex::TempStorage) <= sizeof(sh.storage), "sort storage too small");
  const int tid = threadIdx.x;
  Depth key[kItems];
  int32_t gaussian[kItems];
  bool written[kItems];
  Depth nearest = ~Depth(0), farthest = 0;
  // The run's emission order is arbitrary, so it is read striped (coalesced) and sorted as if blocked.
#pragma unroll
  for (int k = 0; k < kItems; ++k) {
    const int idx = k * kSortThreads + tid;
    written[k] = false;
    key[k] = 0;
    gaussian[k] = -1;
    if (idx < length) {
      const typename Record::Type r = records[begin + idx];
      written[k] = !Record::unwritten(r);
      key[k] = Record::depth(r);
      gaussian[k] = written[k] ? Record::gaussian(r) : -1;
    }
    if (written[k]) {
      nearest = key[k] < nearest ? key[k] : nearest;
      farthest = key[k] > farthest ? key[k] : farthest;
    }
  }
  nearest = warp_min_of(nearest);
  farthest = warp_max_of(farthest);
  if (tid % kWarpSize == 0) {
    sh.warp_min[tid / kWarpSize] = nearest;
    sh.warp_max[tid / kWarpSize] = farthest;
  }
  __syncthreads();
  nearest = sh.warp_min[0];
  farthest = sh.warp_max[0];
#pragma unroll
  for (int w = 1; w < kSortThreads / kWarpSize; ++w) {
    nearest = sh.warp_min[w] < nearest ? sh.warp_min[w] : nearest;
    farthest = sh.warp_max[w] > farthest ? sh.warp_max[w] : farthest;
  }
  // Relative depths fit (farthest - nearest + 1), which marks the slots nothing wrote and the padding: they sort last.
  const Depth last = nearest <= farthest ? farthest - nearest + 1 : Depth(1);
  const int bits = int(sizeof(Depth) * 8) - (sizeof(Depth) == 8 ? __clzll((long long)last) : __clz(int(last)));
#pragma unroll
  for (int k = 0; k < kItems; ++k) key[k] = written[k] ? key[k] - nearest : last;
  Sort(reinterpret_cast<typename Sort::TempStorage&>(sh.storage)).Sort(key, gaussian, 0, bits);

  // Equal depths keep the emission order so far, which the atomics left arbitrary: order them by index.
  sh.first_key[tid] = key[0];
  __syncthreads();
  bool tie = false;
#pragma unroll
  for (int k = 0; k + 1 < kItems; ++k) tie |= key[k] == key[k + 1] && key[k] != last;
  if (tid + 1 < kSortThreads) tie |= key[kItems - 1] == sh.first_key[tid + 1] && key[kItems - 1] != last;
  if (__syncthreads_or(tie)) {
    uint32_t index[kItems];
#pragma unroll
    for (int k = 0; k < kItems; ++k) index[k] = uint32_t(gaussian[k]);  // -1 sorts last
    ByIndex(reinterpret_cast<typename ByIndex::TempStorage&>(sh.storage)).Sort(index, key, 0, 32);
    __syncthreads();
#pragma unroll
    for (int k = 0; k < kItems; ++k) gaussian[k] = int32_t(index[k]);
    Sort(reinterpret_cast<typename Sort::TempStorage&>(sh.storage)).Sort(key, gaussian, 0, bits);  // stable
  }
#pragma unroll
  for (int k = 0; k < kItems; ++k) {
    const int idx = tid * kItems + k;
    if (idx < length) isect_gaussian[begin + idx] = gaussian[k];
  }
}

// Keys per thread of the per-tile sort's instances (about 1.5 times apart, so that padding stays under a third).
constexpr int kSortItemClasses[] = {1, 2, 3, 4, 6, 8, 12, 16};

// The smallest instance of sort_tile_run, from class kClass up to kMaxItems keys per thread, that holds the run.
template <typename T, int kClass, int kMaxItems, typename Shared>
__device__ void sort_tile_sized(Shared& sh, const typename TileRecord<T>::Type* records, int64_t begin, int length,
                                int32_t* isect_gaussian) {
  constexpr int kItems = kSortItemClasses[kClass];
  if constexpr (kItems < kMaxItems) {
    if (length > kItems * kSortThreads) {
      sort_tile_sized<T, kClass + 1, kMaxItems>(sh, records, begin, length, isect_gaussian);
      return;
    }
  }
  sort_tile_run<T, kItems>(sh, records, begin, length, isect_gaussian);
}

// One block per tile, longest first, for runs of at most kMaxItems * kSortThreads records (the host picks kMaxItems
// from the longest run, so that shorter scenes do not pay the registers of longer runs). Runs longer than
// TileRecord<T>::kCapacity never come here: bin_intersections takes the radix path instead.
template <typename T, int kMaxItems>
__global__ void __launch_bounds__(kSortThreads)
    sort_tiles_kernel(const int32_t* tile_order, const int64_t* tile_offsets,
                      const typename TileRecord<T>::Type* records, int32_t* isect_gaussian) {
  __shared__ SortShared<T, kMaxItems> sh;
  const int64_t tile = tile_order[blockIdx.x];
  const int64_t begin = tile_offsets[tile];
  const int length = int(tile_offsets[tile + 1] - begin);
  if (length == 0) return;
  sort_tile_sized<T, 0, kMaxItems>(sh, records, begin, length, isect_gaussian);
}

// ---- radix path (tiles too long for the per-tile sort) ------------------------------------------------------------

template <typename T>
__global__ void depth_key_kernel(const T* projected, const TileRect* tile_rects, int64_t count,
                                 typename DepthBits<T>::Key* keys, int32_t* indices) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= count) return;
  keys[i] = rect_has_tiles(tile_rects[i]) ? DepthBits<T>::of(projected[i * kProjectedWidth + kDepth])
                                          : kCulledDepthKey<T>;
  indices[i] = int32_t(i);
}

__global__ void depth_rank_kernel(const int32_t* sorted, int64_t count, int32_t* depth_rank) {
  const int64_t r = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (r >= count) return;
  depth_rank[sorted[r]] = int32_t(r);
}

// Gaussian-major emission: Gaussian i fills slots [offsets[i], offsets[i + 1]) in row-major tile order.
template <typename T, typename Key>
__global__ void emit_rank_keys_kernel(const ForwardBuffers<T> b, const int64_t* gaussian_offsets,
                                      const int32_t* depth_rank, int64_t count, const TileGrid grid, int rank_bits,
                                      Key* keys) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= count) return;
  int64_t slot = gaussian_offsets[i];
  const int64_t end = gaussian_offsets[i + 1];
  if (slot == end) return;
  const Key rank = Key(depth_rank[i]);
  for_each_touched_tile(b, i, b.tile_rects[i], grid, [&](int64_t tile) {
    if (slot < end) keys[slot] = (Key(tile) << rank_bits) | rank;
    ++slot;
  });
  // Should the tile test ever disagree with project_kernel's, the slots stay in bounds and the surplus carries the
  // tile id one past the last, which sorts after every real tile.
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
  isect_gaussian[k] = tile < tiles ? depth_order[key & rank_mask] : -1;
  const int64_t previous = k == 0 ? -1 : int64_t(keys[k - 1] >> rank_bits);
  const int64_t upto = smaller(tile, tiles);
  for (int64_t t = previous + 1; t <= upto; ++t) tile_offsets[t] = k;
  if (k == count - 1)
    for (int64_t t = upto + 1; t <= tiles; ++t) tile_offsets[t] = count;
}

// ---- forward blend --------------------------------------------------------------------------------------------

struct TilePixel {
  int x, y;
};

__device__ TilePixel tile_pixel(int tile, int tiles_x, int thread) {
  const int warp = thread / kWarpSize, lane = thread % kWarpSize;
  return TilePixel{(tile % tiles_x) * kTileSize + (warp % kWarpBlocksPerRow) * kWarpBlockWidth + lane % kWarpBlockWidth,
                   (tile / tiles_x) * kTileSize + (warp / kWarpBlocksPerRow) * kWarpBlockHeight +
                       lane / kWarpBlockWidth};
}

// Inclusive pixel block of warp `warp` of a tile, clipped to the image (empty when it lies outside).
struct PixelBlock {
  int x0, y0, x1, y1;
};

__device__ PixelBlock warp_block(int tile, const TileGrid& grid, int warp) {
  PixelBlock b;
  b.x0 = (tile % grid.tiles_x) * kTileSize + (warp % kWarpBlocksPerRow) * kWarpBlockWidth;
  b.y0 = (tile / grid.tiles_x) * kTileSize + (warp / kWarpBlocksPerRow) * kWarpBlockHeight;
  b.x1 = smaller(b.x0 + kWarpBlockWidth, grid.width) - 1;
  b.y1 = smaller(b.y0 + kWarpBlockHeight, grid.height) - 1;
  return b;
}

template <typename T, int kChannels> struct ForwardShared {
  T mean_x[kBlendThreads], mean_y[kBlendThreads];
  T conic_a[kBlendThreads], conic_b[kBlendThreads], conic_c[kBlendThreads];
  T opacity[kBlendThreads], depth[kBlendThreads], level[kBlendThreads];
  T features[kChannels][kBlendThreads];
};

// Stores Gaussian `gaussian` at batch position j of any of the shared layouts; Gaussian -1 (an unfilled slot) as one
// that touches no pixel.
template <typename Shared, typename T>
__device__ void store_batch_gaussian(Shared& sh, int j, const T* projected, int32_t gaussian, const T* features,
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

template <typename Shared> __device__ auto batch_gaussian(const Shared& sh, int j) {
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
__device__ bool batch_touches_block(const Shared& sh, int j, int batch_size, const PixelBlock& block) {
  return j < batch_size && pixel_block_touched(batch_gaussian(sh, j), block.x0, block.y0, block.x1, block.y1);
}

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

// ---- backward blend -------------------------------------------------------------------------------------------

template <typename T> __device__ T warp_sum(T v) {
#pragma unroll
  for (int offset = kWarpSize / 2; offset > 0; offset /= 2) v += __shfl_xor_sync(kFullWarp, v, offset);
  return v;
}

// Lane l ends with the warp's total of v[l / 2]. Each level keeps half of a lane's values and trades the other half
// with the lane `offset` away: 16 shuffles for all 16 values instead of 5 per value.
template <int kHalf, typename T> __device__ void keep_half(const T* in, T* out, int lane, int offset) {
  const bool upper = (lane & offset) != 0;
#pragma unroll
  for (int i = 0; i < kHalf; ++i) {
    const T send = upper ? in[i] : in[i + kHalf];
    const T keep = upper ? in[i + kHalf] : in[i];
    out[i] = keep + __shfl_xor_sync(kFullWarp, send, offset);
  }
}

template <typename T> __device__ T warp_transpose_sum(const T (&v)[kReducedValues], int lane) {
  static_assert(kReducedValues == 16 && kWarpSize == 32, "four halving levels, then one plain exchange");
  T eight[8], four[4], two[2], one[1];
  keep_half<8>(v, eight, lane, 16);
  keep_half<4>(eight, four, lane, 8);
  keep_half<2>(four, two, lane, 4);
  keep_half<1>(two, one, lane, 2);
  return one[0] + __shfl_xor_sync(kFullWarp, one[0], 1);
}

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
// registers; the contributing warps' sums are added in warp order, once per (tile, Gaussian).
template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads, kBackwardBlendBlocks<T>)
    blend_backward_kernel(const BlendBackwardParams<T> a, int channel_begin, int channel_count) {
  constexpr int kValues = kProjectedGradWidth + kChannels;
  static_assert(kValues <= kReducedValues, "a Gaussian's gradient values must fit the warp reduction");
  __shared__ BackwardShared<T, kChannels> sh;
  const int tid = threadIdx.x, warp = tid / kWarpSize, lane = tid % kWarpSize;
  const int tile = a.in.tile_order[blockIdx.x];
  const TilePixel pixel = tile_pixel(tile, a.grid.tiles_x, tid);
  const PixelBlock block = warp_block(tile, a.grid, warp);
  const bool inside = pixel.x < a.grid.width && pixel.y < a.grid.height;
  const int64_t pix = int64_t(pixel.y) * a.grid.width + pixel.x;
  const int64_t begin = a.in.tile_offsets[tile];
  const bool first_chunk = channel_begin == 0;
  const BackwardInputs<T>& in = a.in;

  // ---- this thread's pixel
  const int32_t last = inside ? in.contributors[pix] : 0;
  const int32_t warp_last = int32_t(__reduce_max_sync(kFullWarp, unsigned(last)));
  T grad_colour[kChannels];
  T total_dot = T(0);  // image . grad_image over the chunk's channels: everything blended, background included
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
#pragma unroll
  for (int c = 0; c < kChannels; ++c) {
    const T partial = warp_sum(final_t * grad_colour[c]);
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
  if (first_chunk && tid == 0) a.tile_limits[tile] = limit;

  const T px = T(pixel.x) + T(kPixelCentre), py = T(pixel.y) + T(kPixelCentre);
  T transmittance = T(1), running_dot = T(0), running_depth = T(0);
  for (int32_t batch = 0; batch < limit; batch += kBackwardBatch) {
    const int batch_size = int(smaller<int32_t>(kBackwardBatch, limit - batch));
    if (tid < batch_size) {
      const int32_t gaussian = in.isect_gaussian[begin + batch + tid];
      sh.gaussian[tid] = gaussian;
      store_batch_gaussian(sh, tid, in.projected, gaussian, a.features, a.channels, channel_begin, channel_count);
    }
    __syncthreads();

    uint32_t contributed = 0;
    const int reach = int(smaller<int32_t>(batch_size, warp_last - batch));  // past it no pixel of the warp blends
    for (unsigned hits = __ballot_sync(kFullWarp, batch_touches_block(sh, lane, reach, block)); hits != 0;
         hits &= hits - 1) {
      const int j = __ffs(hits) - 1;
      const ProjectedGaussian<T> g = batch_gaussian(sh, j);
      PairAlpha<T> pair;
      const bool blended = batch + j < last && pair_alpha(g, px, py, pair);
      if (!__any_sync(kFullWarp, blended)) continue;
      contributed |= 1u << j;
      T grad[kReducedValues];
#pragma unroll
      for (int f = 0; f < kReducedValues; ++f) grad[f] = T(0);
      if (blended) {
        const T weight = pair.alpha * transmittance;
        T dot = T(0);
#pragma unroll
        for (int c = 0; c < kChannels; ++c) {
          dot += sh.features[c][j] * grad_colour[c];
          grad[kProjectedGradWidth + c] = weight * grad_colour[c];
        }
        running_dot += weight * dot;
        running_depth += weight * g.depth;
        grad[kGradDepth] = weight * grad_depth;
        const T grad_pair_alpha =
            composite_grad_alpha(pair.alpha, transmittance, dot, total_dot - running_dot, g.depth, grad_depth,
                                 depth_sum - running_depth, final_t, grad_alpha);
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
        transmittance *= T(1) - pair.alpha;
      }
      const T total = warp_transpose_sum(grad, lane);
      if (lane % 2 == 0 && lane / 2 < kValues) sh.warp_grad[warp][j][lane / 2] = total;
    }
    if (lane == 0) sh.warp_contributed[warp] = contributed;
    __syncthreads();

    // Gaussian j's gradient over the tile: the contributing warps' sums, added in warp order.
    for (int item = tid; item < batch_size * kValues; item += kBlendThreads) {
      const int j = item / kValues, f = item % kValues;
      T sum = T(0);
      for (int w = 0; w < kBlendWarps; ++w)
        if ((sh.warp_contributed[w] >> j) & 1u) sum += sh.warp_grad[w][j][f];
      const bool feature = f >= kProjectedGradWidth;
      const int channel = channel_begin + f - kProjectedGradWidth;
      if (feature && f - kProjectedGradWidth >= channel_count) continue;
      if (a.deterministic) {
        T* slot = a.slots + (begin + batch + j) * (kProjectedGradWidth + a.channels);
        if (feature) slot[kProjectedGradWidth + channel] = sum;
        else slot[f] = first_chunk ? sum : slot[f] + sum;
      } else if (sum != T(0)) {
        const int64_t gaussian = sh.gaussian[j];
        atomicAdd(feature ? a.grad_features + gaussian * a.channels + channel
                          : a.grad_projected + gaussian * kProjectedGradWidth + f,
                  sum);
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
    if (other_depth < depth || (other_depth == depth && other < gaussian)) lo = mid + 1;
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
    const T depth = visible ? a.in.projected[i * kProjectedWidth + kDepth] : T(0);
    for (int ty = r.y0; visible && ty <= r.y1; ++ty)
      for (int tx = r.x0; tx <= r.x1; ++tx) {
        const int64_t k = find_intersection(a, int64_t(ty) * a.grid.tiles_x + tx, depth, int32_t(i));
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

// Per-tile path: records into each tile's run, then one shared-memory sort per tile.
template <typename T>
void bin_per_tile(const SplatScene<T>& s, const ForwardBuffers<T>& b, int64_t intersections, int64_t longest,
                  const ScratchAllocator& scratch, cudaStream_t stream) {
  using Record = typename TileRecord<T>::Type;
  const TileGrid grid = make_grid(s.camera);
  Record* records = allocate<Record>(scratch, intersections);
  const int64_t buckets = tile_count(grid) * kTileBuckets;
  unsigned* cursors = allocate<unsigned>(scratch, buckets);
  {
    const Stage stage("emit", stream);
    // All one bits: the mark of a slot that emission did not write.
    check_cuda(cudaMemsetAsync(records, 0xff, sizeof(Record) * intersections, stream), "record reset");
    check_cuda(cudaMemsetAsync(cursors, 0, sizeof(unsigned) * buckets, stream), "cursor reset");
    emit_tile_records_kernel<T><<<blocks_for(s.count, kLinearThreads), kLinearThreads, 0, stream>>>(
        b, s.count, grid, cursors, records);
    check_cuda(cudaGetLastError(), "emit_tile_records_kernel launch");
  }
  const Stage stage("tile sort", stream);
  const unsigned tiles = unsigned(tile_count(grid));
  const auto launch = [&](auto max_items) {
    sort_tiles_kernel<T, decltype(max_items)::value>
        <<<tiles, kSortThreads, 0, stream>>>(b.tile_order, b.tile_offsets, records, b.isect_gaussian);
  };
  // The smallest class that holds the longest run (bin_intersections guarantees one does).
  const int64_t items = (longest + kSortThreads - 1) / kSortThreads;
  if (items <= 1) launch(std::integral_constant<int, 1>{});
  else if (items <= 2) launch(std::integral_constant<int, 2>{});
  else if (items <= 3) launch(std::integral_constant<int, 3>{});
  else if (items <= 4) launch(std::integral_constant<int, 4>{});
  else if (items <= 6) launch(std::integral_constant<int, 6>{});
  else if (items <= 8 || kMaxSortItems<T> == 8) launch(std::integral_constant<int, 8>{});
  else if (items <= 12) launch(std::integral_constant<int, std::min(12, kMaxSortItems<T>)>{});
  else launch(std::integral_constant<int, kMaxSortItems<T>>{});
  check_cuda(cudaGetLastError(), "sort_tiles_kernel launch");
}

// Radix path: depth ranks from a global sort, then (tile, rank) keys radix sorted and cut into tile ranges.
template <typename T, typename Key>
void bin_radix(const SplatScene<T>& s, const ForwardBuffers<T>& b, int64_t intersections, int rank_bits,
               int key_bits, const ScratchAllocator& scratch, cudaStream_t stream) {
  const TileGrid grid = make_grid(s.camera);
  const unsigned gaussian_blocks = blocks_for(s.count, kLinearThreads);
  int32_t* depth_order = allocate<int32_t>(scratch, s.count);
  int32_t* depth_rank = allocate<int32_t>(scratch, s.count);
  {
    const Stage stage("depth sort", stream);
    using DepthKey = typename DepthBits<T>::Key;
    cub::DoubleBuffer<DepthKey> depth_keys(allocate<DepthKey>(scratch, s.count), allocate<DepthKey>(scratch, s.count));
    cub::DoubleBuffer<int32_t> indices(allocate<int32_t>(scratch, s.count), depth_order);
    depth_key_kernel<T><<<gaussian_blocks, kLinearThreads, 0, stream>>>(b.projected, b.tile_rects, s.count,
                                                                       depth_keys.Current(), indices.Current());
    check_cuda(cudaGetLastError(), "depth_key_kernel launch");
    // Radix sort is stable: equal depths keep index order, as the CPU reference's stable sort does.
    std::size_t temp_bytes = 0;
    check_cuda(cub::DeviceRadixSort::SortPairs(nullptr, temp_bytes, depth_keys, indices, s.count, 0,
                                               DepthBits<T>::kBits, stream),
               "depth sort size query");
    void* temp = allocate<unsigned char>(scratch, int64_t(temp_bytes));
    check_cuda(cub::DeviceRadixSort::SortPairs(temp, temp_bytes, depth_keys, indices, s.count, 0,
                                               DepthBits<T>::kBits, stream),
               "depth sort");
    depth_order = indices.Current();
    depth_rank_kernel<<<gaussian_blocks, kLinearThreads, 0, stream>>>(depth_order, s.count, depth_rank);
    check_cuda(cudaGetLastError(), "depth_rank_kernel launch");
  }
  cub::DoubleBuffer<Key> keys(allocate<Key>(scratch, intersections), allocate<Key>(scratch, intersections));
  {
    const Stage stage("emit", stream);
    int64_t* gaussian_offsets = allocate<int64_t>(scratch, s.count + 1);
    check_cuda(cudaMemsetAsync(gaussian_offsets, 0, sizeof(int64_t), stream), "offset reset");
    std::size_t temp_bytes = 0;
    check_cuda(cub::DeviceScan::InclusiveSum(nullptr, temp_bytes, b.gaussian_tile_counts, gaussian_offsets + 1,
                                             s.count, stream),
               "tile count scan size query");
    void* temp = allocate<unsigned char>(scratch, int64_t(temp_bytes));
    check_cuda(cub::DeviceScan::InclusiveSum(temp, temp_bytes, b.gaussian_tile_counts, gaussian_offsets + 1, s.count,
                                             stream),
               "tile count scan");
    emit_rank_keys_kernel<T, Key><<<gaussian_blocks, kLinearThreads, 0, stream>>>(
        b, gaussian_offsets, depth_rank, s.count, grid, rank_bits, keys.Current());
    check_cuda(cudaGetLastError(), "emit_rank_keys_kernel launch");
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
        keys.Current(), intersections, rank_bits, tile_count(grid), depth_order, b.isect_gaussian, b.tile_offsets);
    check_cuda(cudaGetLastError(), "tile_ranges_kernel launch");
  }
}

}  // namespace

void set_stage_observer(StageObserver* observer) { g_stage_observer = observer; }
void set_binning(Binning binning) { g_binning = binning; }
Binning last_binning() { return g_last_binning; }
void set_tile_order(TileOrder order) { g_tile_order = order; }

template <typename T>
void project_gaussians(const SplatScene<T>& s, ForwardBuffers<T>& b, const ScratchAllocator& scratch,
                       cudaStream_t stream) {
  const Stage stage("project", stream);
  const TileGrid grid = make_grid(s.camera);
  const int64_t tiles = tile_count(grid), buckets = tiles * kTileBuckets + 1;
  b.touched_masks = allocate<uint64_t>(scratch, s.count);
  b.gaussian_tile_counts = allocate<int64_t>(scratch, s.count);
  b.bucket_counts = allocate<unsigned long long>(scratch, buckets);
  b.bucket_offsets = allocate<int64_t>(scratch, buckets);
  check_cuda(cudaMemsetAsync(b.bucket_counts, 0, sizeof(unsigned long long) * buckets, stream), "tile count reset");
  if (s.count > 0) {
    project_kernel<T><<<blocks_for(s.count, kLinearThreads), kLinearThreads, 0, stream>>>(s, b, grid);
    check_cuda(cudaGetLastError(), "project_kernel launch");
  }
  std::size_t temp_bytes = 0;
  check_cuda(cub::DeviceScan::ExclusiveSum(nullptr, temp_bytes, b.bucket_counts, b.bucket_offsets, buckets, stream),
             "bucket scan size query");
  void* temp = allocate<unsigned char>(scratch, int64_t(temp_bytes));
  check_cuda(cub::DeviceScan::ExclusiveSum(temp, temp_bytes, b.bucket_counts, b.bucket_offsets, buckets, stream),
             "bucket scan");
  finalize_tiles_kernel<<<1, kFinalizeThreads, 0, stream>>>(b.bucket_offsets, tiles, b.tile_offsets, b.tile_order,
                                                           b.bin_stats, g_tile_order == TileOrder::kRowMajor);
  check_cuda(cudaGetLastError(), "finalize_tiles_kernel launch");
}

template <typename T>
void bin_intersections(const SplatScene<T>& s, const ForwardBuffers<T>& b, const BinStats& stats,
                       const ScratchAllocator& scratch, cudaStream_t stream) {
  const int64_t intersections = stats.intersections;
  if (intersections == 0) return;  // the tile offsets are all zero already
  const TileGrid grid = make_grid(s.camera);
  if (g_binning == Binning::kAuto && stats.max_tile_length <= TileRecord<T>::kCapacity) {
    g_last_binning = Binning::kAuto;
    bin_per_tile(s, b, intersections, stats.max_tile_length, scratch, stream);
    return;
  }
  g_last_binning = Binning::kRadix;
  // Ranks need bit_width(N - 1) bits; tile ids up to and including the one-past-the-last sentinel.
  const int rank_bits = std::max(1, bit_width(uint64_t(s.count - 1)));
  const int key_bits = rank_bits + bit_width(uint64_t(tile_count(grid)));
  if (key_bits <= 32)
    bin_radix<T, uint32_t>(s, b, intersections, rank_bits, key_bits, scratch, stream);
  else
    bin_radix<T, uint64_t>(s, b, intersections, rank_bits, key_bits, scratch, stream);
}

template <typename T> void blend(const SplatScene<T>& s, const ForwardBuffers<T>& b, cudaStream_t stream) {
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
    if (s.count > 0) {
      check_cuda(cudaMemsetAsync(blend.grad_projected, 0, sizeof(T) * s.count * kProjectedGradWidth, stream),
                 "gradient accumulator reset");
      check_cuda(cudaMemsetAsync(out.features, 0, sizeof(T) * s.count * s.channels, stream),
                 "feature gradient reset");
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
  template void project_gaussians<T>(const SplatScene<T>&, ForwardBuffers<T>&, const ScratchAllocator&,            \
                                     cudaStream_t);                                                                 \
  template void bin_intersections<T>(const SplatScene<T>&, const ForwardBuffers<T>&, const BinStats&,              \
                                     const ScratchAllocator&, cudaStream_t);                                        \
  template void blend<T>(const SplatScene<T>&, const ForwardBuffers<T>&, cudaStream_t);                              \
  template void backward<T>(const SplatScene<T>&, const BackwardInputs<T>&, const Gradients<T>&, bool,             \
                            const ScratchAllocator&, cudaStream_t);
SFGS_INSTANTIATE(float)
SFGS_INSTANTIATE(double)
#undef SFGS_INSTANTIATE

}  // namespace sfgs::splat::cuda_kernels
