// CUDA binning stage (rasterize_kernels.h): every Gaussian's intersections go into its buckets of each touched
// tile's run and each run is sorted in shared memory by (depth, index); tiles longer than that sort holds send the
// whole pass to the radix path (a global depth sort, then (tile, depth rank) keys). Both give the same lists.
#include <cub/block/block_radix_sort.cuh>
#include <cub/device/device_radix_sort.cuh>
#include <cub/device/device_scan.cuh>

#include "ops/splat/cuda/kernel_common.cuh"

namespace sfgs::splat::cuda_kernels {
namespace {

// Threads of the per-tile sort; its radix digit width (at a few keys per thread, the digit counters' shared-memory
// traffic grows faster with the width than passes shrink).
constexpr int kSortThreads = 256;
constexpr int kSortRadixBits = 4;
// Emission issues the atomics of up to this many tiles before it uses their results.
constexpr int kEmitBatch = 8;

int bit_width(uint64_t v) {
  int bits = 0;
  for (; v != 0; v >>= 1) ++bits;
  return bits;
}

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
template <typename T>
constexpr typename DepthBits<T>::Key kCulledDepthKey = (typename DepthBits<T>::Key(1) << DepthBits<T>::kBits) - 1;

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
  count_touched_tiles(load_projected(b.projected + gaussian * kProjectedWidth), PixelRect{r.x0, r.y0, r.x1, r.y1}, grid,
                      [&](int tx, int ty) { visit(int64_t(ty) * grid.tiles_x + tx); });
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
  keys[i] =
      rect_has_tiles(tile_rects[i]) ? DepthBits<T>::of(projected[i * kProjectedWidth + kDepth]) : kCulledDepthKey<T>;
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

template <typename Key> __global__ void fill_keys_kernel(Key* keys, int64_t count, Key value) {
  const int64_t k = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (k < count) keys[k] = value;
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

// ---- host side ----------------------------------------------------------------------------------------------------

// Per-tile path: records into each tile's run, then one shared-memory sort per tile.
template <typename T>
void bin_per_tile(const SplatScene<T>& s, const ForwardBuffers<T>& b, int64_t intersections, int64_t longest,
                  const ScratchAllocator& scratch, cudaStream_t stream) {
  using Record = typename TileRecord<T>::Type;
  const TileGrid grid = grid_of(s);
  Record* records = allocate<Record>(scratch, intersections);
  const int64_t buckets = tile_count(grid) * kTileBuckets;
  unsigned* cursors = allocate<unsigned>(scratch, buckets);
  {
    const Stage stage("emit", stream);
    // All one bits: the mark of a slot that emission did not write.
    check_cuda(cudaMemsetAsync(records, 0xff, sizeof(Record) * intersections, stream), "record reset");
    check_cuda(cudaMemsetAsync(cursors, 0, sizeof(unsigned) * buckets, stream), "cursor reset");
    emit_tile_records_kernel<T>
        <<<blocks_for(s.count, kLinearThreads), kLinearThreads, 0, stream>>>(b, s.count, grid, cursors, records);
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
  if (items <= 1)
    launch(std::integral_constant<int, 1>{});
  else if (items <= 2)
    launch(std::integral_constant<int, 2>{});
  else if (items <= 3)
    launch(std::integral_constant<int, 3>{});
  else if (items <= 4)
    launch(std::integral_constant<int, 4>{});
  else if (items <= 6)
    launch(std::integral_constant<int, 6>{});
  else if (items <= 8 || kMaxSortItems<T> == 8)
    launch(std::integral_constant<int, 8>{});
  else if (items <= 12)
    launch(std::integral_constant<int, std::min(12, kMaxSortItems<T>)>{});
  else
    launch(std::integral_constant<int, kMaxSortItems<T>>{});
  check_cuda(cudaGetLastError(), "sort_tiles_kernel launch");
}

// Radix path: depth ranks from a global sort, then (tile, rank) keys radix sorted and cut into tile ranges.
template <typename T, typename Key>
void bin_radix(const SplatScene<T>& s, const ForwardBuffers<T>& b, int64_t intersections, int rank_bits, int key_bits,
               const ScratchAllocator& scratch, cudaStream_t stream) {
  const TileGrid grid = grid_of(s);
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
    check_cuda(
        cub::DeviceRadixSort::SortPairs(temp, temp_bytes, depth_keys, indices, s.count, 0, DepthBits<T>::kBits, stream),
        "depth sort");
    depth_order = indices.Current();
    depth_rank_kernel<<<gaussian_blocks, kLinearThreads, 0, stream>>>(depth_order, s.count, depth_rank);
    check_cuda(cudaGetLastError(), "depth_rank_kernel launch");
  }
  cub::DoubleBuffer<Key> keys(allocate<Key>(scratch, intersections), allocate<Key>(scratch, intersections));
  {
    const Stage stage("emit", stream);
    // Slots no Gaussian fills (a budgeted pass's buffers are larger than its intersections) keep the tile id one
    // past the last: they sort after every real key and tile_ranges_kernel gives them to no tile.
    fill_keys_kernel<Key><<<blocks_for(intersections, kLinearThreads), kLinearThreads, 0, stream>>>(
        keys.Current(), intersections, Key(tile_count(grid)) << rank_bits);
    check_cuda(cudaGetLastError(), "fill_keys_kernel launch");
    int64_t* gaussian_offsets = allocate<int64_t>(scratch, s.count + 1);
    check_cuda(cudaMemsetAsync(gaussian_offsets, 0, sizeof(int64_t), stream), "offset reset");
    std::size_t temp_bytes = 0;
    check_cuda(cub::DeviceScan::InclusiveSum(nullptr, temp_bytes, b.gaussian_tile_counts, gaussian_offsets + 1, s.count,
                                             stream),
               "tile count scan size query");
    void* temp = allocate<unsigned char>(scratch, int64_t(temp_bytes));
    check_cuda(
        cub::DeviceScan::InclusiveSum(temp, temp_bytes, b.gaussian_tile_counts, gaussian_offsets + 1, s.count, stream),
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
    check_cuda(cub::DeviceRadixSort::SortKeys(temp, temp_bytes, keys, intersections, 0, key_bits, stream), "tile sort");
  }
  {
    const Stage stage("tile ranges", stream);
    tile_ranges_kernel<Key><<<blocks_for(intersections, kLinearThreads), kLinearThreads, 0, stream>>>(
        keys.Current(), intersections, rank_bits, tile_count(grid), depth_order, b.isect_gaussian, b.tile_offsets);
    check_cuda(cudaGetLastError(), "tile_ranges_kernel launch");
  }
}

// Copies the pass's BinStats for the caller and, when the pass exceeds the budget or has invalid opacities, zeroes
// every bucket and tile offset and every Gaussian's tile count: emission then writes nothing (on either path), the
// tile sorts and the blends see empty tiles.
__global__ void apply_bin_budget_kernel(const BinStats* stats, BinBudget budget, int64_t* bucket_offsets,
                                        int64_t bucket_entries, int64_t* tile_offsets, int64_t tile_entries,
                                        int64_t* gaussian_tile_counts, int64_t gaussians) {
  const BinStats s = *stats;
  const int64_t first = int64_t(blockIdx.x) * blockDim.x + threadIdx.x, stride = int64_t(gridDim.x) * blockDim.x;
  if (first == 0) *budget.reported = s;
  if (s.intersections <= budget.intersections && s.max_tile_length <= budget.max_tile_length &&
      s.invalid_opacities == 0)
    return;
  for (int64_t k = first; k < bucket_entries; k += stride) bucket_offsets[k] = 0;
  for (int64_t k = first; k < tile_entries; k += stride) tile_offsets[k] = 0;
  for (int64_t k = first; k < gaussians; k += stride) gaussian_tile_counts[k] = 0;
}

}  // namespace

template <typename T>
BinStats apply_bin_budget(const SplatScene<T>& s, const ForwardBuffers<T>& b, const BinBudget& budget,
                          cudaStream_t stream) {
  const int64_t tiles = tile_count(grid_of(s));
  const int64_t buckets = tiles * kTileBuckets + 1;
  apply_bin_budget_kernel<<<blocks_for(std::max(buckets, s.count), kLinearThreads), kLinearThreads, 0, stream>>>(
      b.bin_stats, budget, b.bucket_offsets, buckets, b.tile_offsets, tiles + 1, b.gaussian_tile_counts, s.count);
  check_cuda(cudaGetLastError(), "apply_bin_budget_kernel launch");
  return BinStats{budget.intersections, budget.max_tile_length, 0};
}

template <typename T>
void bin_intersections(const SplatScene<T>& s, const ForwardBuffers<T>& b, const BinStats& stats,
                       const ScratchAllocator& scratch, cudaStream_t stream) {
  const int64_t intersections = stats.intersections;
  if (intersections == 0) return;  // the tile offsets are all zero already
  const TileGrid grid = grid_of(s);
  if (requested_binning() == Binning::kAuto && stats.max_tile_length <= TileRecord<T>::kCapacity) {
    record_binning(Binning::kAuto);
    bin_per_tile(s, b, intersections, stats.max_tile_length, scratch, stream);
    return;
  }
  record_binning(Binning::kRadix);
  // Ranks need bit_width(N - 1) bits; tile ids up to and including the one-past-the-last sentinel.
  const int rank_bits = std::max(1, bit_width(uint64_t(s.count - 1)));
  const int key_bits = rank_bits + bit_width(uint64_t(tile_count(grid)));
  if (key_bits <= 32)
    bin_radix<T, uint32_t>(s, b, intersections, rank_bits, key_bits, scratch, stream);
  else
    bin_radix<T, uint64_t>(s, b, intersections, rank_bits, key_bits, scratch, stream);
}

template BinStats apply_bin_budget<float>(const SplatScene<float>&, const ForwardBuffers<float>&, const BinBudget&,
                                          cudaStream_t);
template BinStats apply_bin_budget<double>(const SplatScene<double>&, const ForwardBuffers<double>&, const BinBudget&,
                                           cudaStream_t);
template void bin_intersections<float>(const SplatScene<float>&, const ForwardBuffers<float>&, const BinStats&,
                                       const ScratchAllocator&, cudaStream_t);
template void bin_intersections<double>(const SplatScene<double>&, const ForwardBuffers<double>&, const BinStats&,
                                        const ScratchAllocator&, cudaStream_t);

}  // namespace sfgs::splat::cuda_kernels
