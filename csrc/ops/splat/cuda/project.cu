// CUDA projection stage (rasterize_kernels.h): one thread per Gaussian culls, projects and tile-tests it
// (ops/splat/stages.h, as the CPU reference does) and counts its intersections per tile bucket; a scan and one block
// then give every tile's offset, the blends' tile order and BinStats.
#include <cub/device/device_scan.cuh>

#include "ops/splat/cuda/kernel_common.cuh"

namespace sfgs::splat::cuda_kernels {
namespace {

// Threads of the one-block tile finalisation.
constexpr int kFinalizeThreads = 1024;
// Tiles are blended longest first: classes by bit width of the run length, then the empty tiles.
constexpr int kLengthClasses = 33;

template <typename T>
__global__ void project_kernel(const SplatScene<T> s, const ForwardBuffers<T> b, const TileGrid grid) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= s.count) return;
  const T opacity = s.opacities[i];
  if (!(opacity >= T(0) && opacity <= T(1)))  // NaN fails both comparisons
    atomicAdd(reinterpret_cast<unsigned long long*>(&b.bin_stats->invalid_opacities), 1ull);
  int64_t touched = 0;
  uint64_t mask = 0;
  TileRect rect{1, 1, 0, 0};
  int32_t radius_x = 0, radius_y = 0;
  ProjectedGaussian<T> g;
  PixelRect t;
  Vec2<T> radius;
  if (project_to_tiles(s, i, g, t, radius)) {
    const int width = t.x1 - t.x0 + 1;
    const bool masked = rect_area(t) <= kMaskedRectTiles;
    touched = count_touched_tiles(g, t, grid, [&](int tx, int ty) {
      atomicAdd(b.bucket_counts + (int64_t(ty) * grid.tiles_x + tx) * kTileBuckets + i % kTileBuckets, 1ull);
      if (masked) mask |= uint64_t(1) << ((ty - t.y0) * width + (tx - t.x0));
    });
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

// One block, after the exclusive scan of the bucket counts: each tile's offset (tiles + 1 entries, the last the
// intersection count), BinStats' intersection count and longest tile, and the tile order of the blends (longest runs
// first, the empty tiles last, or row-major).
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
    for (int w = 0; w < kFinalizeThreads / kWarpSize; ++w)
      longest = warp_longest[w] > longest ? warp_longest[w] : longest;
    const int64_t total = bucket_offsets[tiles * kTileBuckets];
    tile_offsets[tiles] = total;
    stats->intersections = total;
    stats->max_tile_length = int64_t(longest);
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

}  // namespace

template <typename T>
void project_gaussians(const SplatScene<T>& s, ForwardBuffers<T>& b, const ScratchAllocator& scratch,
                       cudaStream_t stream) {
  const Stage stage("project", stream);
  const TileGrid grid = grid_of(s);
  const int64_t tiles = tile_count(grid), buckets = tiles * kTileBuckets + 1;
  b.touched_masks = allocate<uint64_t>(scratch, s.count);
  b.gaussian_tile_counts = allocate<int64_t>(scratch, s.count);
  b.bucket_counts = allocate<unsigned long long>(scratch, buckets);
  b.bucket_offsets = allocate<int64_t>(scratch, buckets);
  check_cuda(cudaMemsetAsync(b.bucket_counts, 0, sizeof(unsigned long long) * buckets, stream), "tile count reset");
  check_cuda(cudaMemsetAsync(b.bin_stats, 0, sizeof(BinStats), stream), "bin stats reset");
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
                                                            b.bin_stats, tile_order() == TileOrder::kRowMajor);
  check_cuda(cudaGetLastError(), "finalize_tiles_kernel launch");
}

template void project_gaussians<float>(const SplatScene<float>&, ForwardBuffers<float>&, const ScratchAllocator&,
                                       cudaStream_t);
template void project_gaussians<double>(const SplatScene<double>&, ForwardBuffers<double>&, const ScratchAllocator&,
                                        cudaStream_t);

}  // namespace sfgs::splat::cuda_kernels
