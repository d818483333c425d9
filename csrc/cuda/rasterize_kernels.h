#pragma once
// CUDA kernels of the splatting op, free of torch so that nvcc can compile them without a CUDA LibTorch. The glue
// (splat_cuda.cpp) allocates every buffer that outlives a call as a tensor and passes raw pointers; scratch memory
// comes through a stream-ordered allocator callback, so it too can come from torch's caching allocator.
//
// Forward, in this order on one stream:
//   project_gaussians  projection, radii, tile rectangles, exact per-Gaussian tile counts (tile_touches) and their
//                      inclusive prefix sum: gaussian_offsets[N] is the intersection count.
//   sort_by_depth      every Gaussian's rank in (depth, index) order, by a stable radix sort of depth bits.
//   -- the caller reads gaussian_offsets[N]: the forward pass's one host synchronisation (it sizes the buffers) --
//   bin_and_blend      one key (tile << rank_bits | depth rank) per intersection, radix sort of the keys, tile
//                      ranges, front-to-back blend. Ranks are unique, so the per-tile order is (depth, index)
//                      exactly as in the CPU reference, in float and in double.
// Backward: per tile, the blend is replayed front to back; one warp per 32 consecutive Gaussians of the tile then
// streams the tile's pixels through its lanes (each lane owns one Gaussian), so each lane sums its Gaussian's
// gradient over the tile in registers. Lanes flush once per (tile, Gaussian): with atomics, or, in deterministic
// mode, into that intersection's own slot, which a per-Gaussian kernel sums in a fixed order before the projection VJP.
#include <cstddef>
#include <cstdint>
#include <functional>

#include <cuda_runtime_api.h>

#include "splat/pair_math.h"

namespace sfgs::splat::cuda_kernels {

// Returns device memory of at least `bytes` that stays valid for all work queued on the stream before the
// allocation is released (the glue releases it when the backend call returns).
using ScratchAllocator = std::function<void*(std::size_t bytes)>;

// Layout of one projected Gaussian (the CPU backend uses the same one).
enum ProjectedField : int { kMeanX, kMeanY, kConicA, kConicB, kConicC, kOpacity, kDepth, kLevel, kProjectedWidth };
// Gradient w.r.t. one projected Gaussian, summed over the pixels it was blended into; the feature gradients follow
// it in a deterministic-mode intersection slot.
enum ProjectedGradField : int {
  kGradMeanX, kGradMeanY, kGradConicA, kGradConicB, kGradConicC, kGradOpacity, kGradDepth, kProjectedGradWidth
};

// Inclusive tile rectangle of a Gaussian; empty (x0 > x1) when it touches no tile. Tile coordinates fit in 16 bits
// because image sides are at most kMaxImageSide.
struct TileRect {
  int16_t x0, y0, x1, y1;
};
static_assert(kMaxImageSide / kTileSize <= INT16_MAX, "tile coordinates must fit TileRect");

template <typename T> struct SplatScene {
  PinholeCamera<T> camera;
  ProjectionSettings projection;
  const T* means;        // (N, 3)
  const T* scales;       // (N, 3), null when covariances are given
  const T* rotations;    // (N, 4), null when covariances are given
  const T* covariances;  // (N, 6), null when scales and rotations are given
  const T* opacities;    // (N)
  const T* features;     // (N, C)
  const T* background;   // (C)
  int64_t count;         // N
  int channels;          // C
};

template <typename T> struct ForwardBuffers {
  // Per Gaussian.
  T* projected;               // (N, kProjectedWidth); rows of culled Gaussians are not written
  TileRect* tile_rects;       // (N)
  int32_t* radii;             // (N, 2)
  int64_t* gaussian_offsets;  // (N + 1)
  int32_t* depth_order;       // (N) Gaussian at each depth rank
  int32_t* depth_rank;        // (N) depth rank of each Gaussian
  // Per intersection, in sorted order; given once the intersection count is known.
  int32_t* isect_gaussian;
  // Per tile: start of each tile's run of sorted intersections, (tiles + 1).
  int64_t* tile_offsets;
  // Per pixel.
  T* image;                // (H, W, C)
  T* alpha;                // (H, W)
  T* depth_sum;            // (H, W)
  T* final_transmittance;  // (H, W)
  int32_t* contributors;   // (H, W) index + 1 (within the tile's run) of the last blended Gaussian, 0 for none
};

template <typename T> struct BackwardInputs {
  const T* projected;
  const TileRect* tile_rects;
  const int32_t* depth_rank;
  const int32_t* isect_gaussian;
  const int64_t* tile_offsets;
  int64_t intersection_count;
  const T* image;
  const T* depth_sum;
  const T* final_transmittance;
  const int32_t* contributors;
  const T* grad_image;      // (H, W, C), null when no gradient flows into it
  const T* grad_alpha;      // (H, W), null likewise
  const T* grad_depth_sum;  // (H, W), null likewise
};

// Every array is fully written by backward().
template <typename T> struct Gradients {
  T* means;
  T* scales;       // null when covariances are given
  T* rotations;    // null when covariances are given
  T* covariances;  // null when scales and rotations are given
  T* opacities;
  T* features;
  T* background;
};

template <typename T>
void project_gaussians(const SplatScene<T>& scene, const ForwardBuffers<T>& buffers, const ScratchAllocator& scratch,
                       cudaStream_t stream);
template <typename T>
void sort_by_depth(const SplatScene<T>& scene, const ForwardBuffers<T>& buffers, const ScratchAllocator& scratch,
                   cudaStream_t stream);
template <typename T>
void bin_and_blend(const SplatScene<T>& scene, const ForwardBuffers<T>& buffers, int64_t intersection_count,
                   const ScratchAllocator& scratch, cudaStream_t stream);
// deterministic: bit-identical gradients across runs (per-intersection slots, fixed-order sums) at the cost of
// (7 + C) values of memory per intersection.
template <typename T>
void backward(const SplatScene<T>& scene, const BackwardInputs<T>& inputs, const Gradients<T>& gradients,
              bool deterministic, const ScratchAllocator& scratch, cudaStream_t stream);

// Benchmarks time the pipeline's stages by recording their own events when these are called; the stages are named
// "project", "depth sort", "emit", "tile sort", "tile ranges", "blend", "blend backward" and "project backward".
class StageObserver {
 public:
  virtual void begin(const char* stage, cudaStream_t stream) = 0;
  virtual void end(const char* stage, cudaStream_t stream) = 0;

 protected:
  ~StageObserver() = default;
};
// Installs the observer for all later calls on every thread (null removes it); for benchmarks, not thread-safe.
void set_stage_observer(StageObserver* observer);

}  // namespace sfgs::splat::cuda_kernels
