#pragma once
// CUDA kernels of the splatting op, free of torch so that nvcc can compile them without a CUDA LibTorch. The glue
// (splat_cuda.cpp) allocates every buffer that outlives a call as a tensor and passes raw pointers; scratch memory
// comes through a stream-ordered allocator callback, so it too can come from torch's caching allocator.
//
// Forward, in this order on one stream:
//   project_gaussians  projection, radii, tile rectangles and, with the exact ellipse/tile test, each Gaussian's
//                      touched tiles (a bit mask over its tile rectangle when that has at most 64 tiles) and each
//                      tile's intersection count, spread over 32 counters per tile (Gaussian i counts in i % 32) so
//                      that the atomics do not queue on one address; a scan of the counters gives every bucket's
//                      offset, and one block derives the tiles' offsets, the blends' tile order (longest first) and
//                      BinStats (intersection count, longest tile, and the opacities outside [0, 1] it counted) in
//                      buffers.bin_stats.
//   -- the caller reads BinStats: the forward pass's one host synchronisation (it sizes the buffers, and invalid
//      opacities are reported right after it) --
//   bin_intersections  each Gaussian writes a (depth bits, index) record into the next slot of its bucket of each
//                      touched tile's run, and one block per tile radix sorts its run in shared memory by depth
//                      bits relative to the tile's nearest, carrying the index, with ties re-sorted by index: the
//                      order is (depth, index) exactly as in the CPU reference, in float and in double. A tile longer
//                      than the shared-memory sort holds sends the whole pass to the radix path: a global depth sort
//                      gives every Gaussian a unique rank, keys (tile << rank_bits | rank) are radix sorted and cut
//                      into tile ranges. Both paths give the same lists.
//   blend              front-to-back blend, one CTA per tile (longest tiles first); each warp covers a compact 8 x 4
//                      pixel block and skips, with one ballot per 32 Gaussians, those whose ellipse misses its block
//                      (pixel_block_touched, the tile test on the block: bit-identical per pixel). A run that would
//                      outlast the pass (kBlendCutShare) is cut into segments (kBlendSegmentLength) composited by
//                      separate CTAs and joined by the tile's last (exact but for rounding; blend_forward.cu); a pass
//                      with none takes the uncut kernel alone.
// Backward: one thread per pixel replays the tile's blend front to back (the forward's transmittances, no division);
// warps skip, with the same ballot, the Gaussians that miss their block or lie beyond their pixels' last blended
// Gaussian, and with one vote those that none of their pixels blended. A warp sums its pixels' contributions to a
// Gaussian with a transposing shuffle reduction, and the contributing warps' sums are added in warp order, once per
// (tile, Gaussian): into per-Gaussian accumulators with atomics, or, in deterministic mode, into that
// intersection's own slot, which a per-Gaussian kernel sums in a fixed order before the projection VJP.
//
// Files, by stage: project.cu, binning.cu, blend_forward.cu, blend_backward.cu (with the per-Gaussian backward);
// kernel_common.cuh, warp_utils.cuh and blend_common.cuh hold what they share; diagnostics.h the switches that only
// tests and benchmarks use.
#include <cstddef>
#include <cstdint>
#include <functional>

#include <cuda_runtime_api.h>

#include "ops/splat/stages.h"
#include "ops/splat/constants.h"

namespace sfgs::splat::cuda_kernels {

// Returns device memory of at least `bytes` that stays valid for all work queued on the stream before the
// allocation is released (the glue releases it when the backend call returns).
using ScratchAllocator = std::function<void*(std::size_t bytes)>;

// Inclusive tile rectangle of a Gaussian; empty (x0 > x1) when it touches no tile. Tile coordinates fit in 16 bits
// because image sides are at most kMaxImageSide.
struct TileRect {
  int16_t x0, y0, x1, y1;
};
static_assert(kMaxImageSide / kTileSize <= INT16_MAX, "tile coordinates must fit TileRect");

// What the caller reads after project_gaussians to size the rest of the pass.
struct BinStats {
  int64_t intersections;      // (Gaussian, tile) pairs that pass the tile test
  int64_t max_tile_length;    // intersections of the busiest tile
  int64_t invalid_opacities;  // opacities outside [0, 1] or not finite (an error the caller reports)
};

// Stands in for the host read of BinStats where the pass must not synchronise (a render captured in a CUDA graph):
// the per-intersection buffers are sized from the budget, and a pass beyond it (or with invalid opacities) is
// emptied on the device, so that it blends only the background and never writes past its buffers. The pass's true
// BinStats are copied to `reported` (device memory) for the caller to check once the work is done. A budget whose
// longest tile fits the per-tile sort takes that path; a larger one the radix path, over the budget's slots.
struct BinBudget {
  int64_t intersections;
  int64_t max_tile_length;
  BinStats* reported;
};

template <typename T> struct ForwardBuffers {
  // Per Gaussian.
  T* projected;          // (N, kProjectedWidth); rows of culled Gaussians are not written
  TileRect* tile_rects;  // (N)
  int32_t* radii;        // (N, 2)
  // Per tile: start of each tile's run of sorted intersections, (tiles + 1); the last entry is the count.
  int64_t* tile_offsets;
  // Device copy of BinStats, written by project_gaussians; the caller reads it.
  BinStats* bin_stats;
  // Per intersection, in sorted order; given once the intersection count is known. An entry of -1 (only where the
  // tile test could ever disagree between two evaluations) is a Gaussian that touches nothing.
  int32_t* isect_gaussian;
  // Per tile: the order in which the blends take the tiles (longest runs first, empty tiles last), (tiles).
  int32_t* tile_order;
  // Scratch shared by project_gaussians and bin_intersections (set by project_gaussians).
  uint64_t* touched_masks;            // (N) touched tiles of each Gaussian's tile rectangle, if it has <= 64 tiles
  int64_t* gaussian_tile_counts;      // (N) tiles each Gaussian touches
  unsigned long long* bucket_counts;  // (tiles * buckets + 1) intersections per tile bucket
  int64_t* bucket_offsets;            // (tiles * buckets + 1) exclusive scan of bucket_counts
  // Per pixel; needed by blend only.
  T* image;                // (H, W, C)
  T* alpha;                // (H, W)
  T* depth_sum;            // (H, W) sum of depth * blend weight (kept for backward)
  T* depth;                // (H, W) expected depth (expected_depth_of)
  T* final_transmittance;  // (H, W)
  int32_t* contributors;   // (H, W) index + 1 (within the tile's run) of the last blended Gaussian, 0 for none
};

template <typename T> struct BackwardInputs {
  const T* projected;
  const TileRect* tile_rects;
  const int32_t* isect_gaussian;
  const int64_t* tile_offsets;
  const int32_t* tile_order;
  int64_t intersection_count;
  const T* image;
  const T* depth_sum;
  const T* final_transmittance;
  const int32_t* contributors;
  const T* grad_image;      // (H, W, C), null when no gradient flows into it
  const T* grad_alpha;      // (H, W), null likewise
  const T* grad_depth_sum;  // (H, W), null likewise
};

// Sets buffers' scratch pointers (from `scratch`, which must outlive bin_intersections) and fills bin_stats.
template <typename T>
void project_gaussians(const SplatScene<T>& scene, ForwardBuffers<T>& buffers, const ScratchAllocator& scratch,
                       cudaStream_t stream);
// Instead of reading buffers.bin_stats: applies `budget` on the device (see BinBudget) and returns the stats
// bin_intersections is to size its work by.
template <typename T>
BinStats apply_bin_budget(const SplatScene<T>& scene, const ForwardBuffers<T>& buffers, const BinBudget& budget,
                          cudaStream_t stream);
// stats: the values project_gaussians wrote to buffers.bin_stats, or those apply_bin_budget returned.
template <typename T>
void bin_intersections(const SplatScene<T>& scene, const ForwardBuffers<T>& buffers, const BinStats& stats,
                       const ScratchAllocator& scratch, cudaStream_t stream);
// stats: as for bin_intersections (its intersection count bounds the work lists of the split tiles); stats_exact:
// they are the pass's own (read on the host), not a budget's bounds, so the host can tell that no run is cut.
template <typename T>
void blend(const SplatScene<T>& scene, const ForwardBuffers<T>& buffers, const BinStats& stats, bool stats_exact,
           const ScratchAllocator& scratch, cudaStream_t stream);
// deterministic: bit-identical gradients across runs (per-intersection slots, fixed-order sums) at the cost of
// (7 + C) values of memory per intersection. Every array of gradients is fully written.
template <typename T>
void backward(const SplatScene<T>& scene, const BackwardInputs<T>& inputs, const Gradients<T>& gradients,
              bool deterministic, const ScratchAllocator& scratch, cudaStream_t stream);

}  // namespace sfgs::splat::cuda_kernels
