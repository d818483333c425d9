// CUDA forward blend (rasterize_kernels.h): one thread per pixel, front to back over the tile's sorted run. A tile
// takes one block; a tile whose run would outlast the pass (kBlendCutShare) is cut into segments of
// kBlendSegmentLength that separate blocks composite at once, and the tile's last segment to finish joins them.
// Without this, the few longest runs (the face and hands, where the avatar's finest Gaussians pile up) are each one
// block's serial work and set the pass's time. Cutting costs work: a segment composites its whole run even where the
// pixels' transmittance already ran out in an earlier segment, so only the runs that set the pass's length are cut,
// and a pass that the host can tell has none (from its intersection count and longest run) takes the uncut kernel,
// unplanned.
//
// Joining is exact but for rounding. Segment k composites its run from a transmittance of 1, giving (colour_k,
// depth_k, T_k); a pixel entering it with transmittance T takes colour + T colour_k and T T_k, which is what the
// serial loop gives as long as T T_k stays >= kMinTransmittance: the transmittance only falls, so no Gaussian of the
// segment would have stopped the serial loop. At the first segment where it would not stay, that segment's block of a
// second kernel composites it again from the pixel's true transmittance, with the serial loop's stop rule, and the
// rest is ignored; a pixel entering that segment with a transmittance of exactly 1 takes the segment's own composite,
// which is the serial loop's.
#include <cub/block/block_scan.cuh>
#include <type_traits>

#include "ops/splat/cuda/blend_common.cuh"
#include "ops/splat/constants.h"

namespace sfgs::splat::cuda_kernels {
namespace {

// Resident blocks per multiprocessor that the float kernel is register-limited for (40 registers, no spills); double
// keeps the compiler's choice.
template <typename T> constexpr int kForwardBlendBlocks = std::is_same_v<T, float> ? 6 : 1;
constexpr int kPlanThreads = 1024;

// Which runs the blend cuts into segments of segment_length: those longer than a segment and than `share` times the
// pass's intersections per resident block (kBlendCutShare says why).
struct CutRule {
  int64_t segment_length;
  int64_t resident_blocks;
  double share;
  // The longest run left whole in a pass of `intersections`.
  __host__ __device__ int64_t longest_uncut(int64_t intersections) const {
    const int64_t balanced = int64_t(share * double(intersections) / double(resident_blocks));
    return balanced > segment_length ? balanced : segment_length;
  }
};

template <typename T, int kChannels> struct ForwardShared {
  T mean_x[kBlendThreads], mean_y[kBlendThreads];
  T conic_a[kBlendThreads], conic_b[kBlendThreads], conic_c[kBlendThreads];
  T opacity[kBlendThreads], depth[kBlendThreads], level[kBlendThreads];
  T features[kChannels][kBlendThreads];
};

// One block's work: a segment [begin, end) of a tile's run.
struct BlendSegment {
  int32_t tile;
  int32_t split;  // the tile's index among the split tiles; -1: the segment is the whole run (the block writes the
                  // pixels)
  int32_t slot;   // its partial composite's slot, when split
  int64_t begin, end;
};

// A tile cut into segments, whose partials occupy slots [first_partial, first_partial + segments).
struct SplitTile {
  int32_t tile, first_partial, segments;
};

// The work lists plan_segments_kernel writes, sized for the most work the pass's intersection count allows.
struct SegmentPlan {
  BlendSegment* segments;
  SplitTile* split_tiles;
  int32_t* arrivals;  // per split tile: its segments finished so far (the last to finish joins them)
  int32_t* count;     // segments
  CutRule cut;
};

template <typename T> struct PartialComposites {
  T* values;      // per slot and pixel: the chunk's colours, transmittance (negated where the segment's own
                  // composite stopped: the serial loop stops inside it whatever the entering transmittance), depth sum
  int32_t* last;  // per slot and pixel: run position + 1 of the last blended Gaussian, 0 for none
};

template <typename T> struct BlendForwardParams {
  ForwardBuffers<T> b;
  const T* features;
  const T* background;
  int channels;
  TileGrid grid;
  SegmentPlan plan;
  PartialComposites<T> partials;
};

template <typename T, int kChannels> struct PixelComposite {
  T transmittance, depth;
  T colour[kChannels];
  int32_t last;
  __device__ PixelComposite() : transmittance(T(1)), depth(T(0)), last(0) {
#pragma unroll
    for (int c = 0; c < kChannels; ++c) colour[c] = T(0);
  }
};

template <typename T> struct BlockPixel {
  int x, y;
  bool inside;
  T px, py;
  PixelBlock block;
};

template <typename T> __device__ BlockPixel<T> block_pixel(int tile, const TileGrid& grid) {
  const TilePixel pixel = tile_pixel(tile, grid.tiles_x, threadIdx.x);
  BlockPixel<T> p;
  p.x = pixel.x;
  p.y = pixel.y;
  p.inside = p.x < grid.width && p.y < grid.height;
  p.px = T(p.x) + T(kPixelCentre);
  p.py = T(p.y) + T(kPixelCentre);
  p.block = warp_block(tile, grid, int(threadIdx.x) / kWarpSize);
  return p;
}

// Composites intersections [lo, hi) of the tile's run (starting at run_begin)
// into `pixel` with the serial stop rule; a thread that is `done` takes part in
// the loads only. Every thread of the block must call it. Each warp walks a
// batch 32 Gaussians at a time: one ballot of the block test gives the
// Gaussians that can reach its pixel block, and only those are evaluated, in
// order, so every pixel sees exactly the pairs (and arithmetic) of the plain
// loop.
template <typename T, int kChannels>
__device__ void composite_run(ForwardShared<T, kChannels>& sh, const BlendForwardParams<T>& a, int channel_begin,
                              int channel_count, const BlockPixel<T>& at, int64_t run_begin, int64_t lo, int64_t hi,
                              PixelComposite<T, kChannels>& pixel, bool& done) {
  const int lane = int(threadIdx.x) % kWarpSize;
  for (int64_t batch = lo; batch < hi; batch += kBlendThreads) {
    // Also the barrier that lets the previous batch's readers finish before it
    // is overwritten.
    if (__syncthreads_count(done) == kBlendThreads) break;
    if (batch + threadIdx.x < hi)
      store_batch_gaussian(sh, threadIdx.x, a.b.projected, a.b.isect_gaussian[batch + threadIdx.x], a.features,
                           a.channels, channel_begin, channel_count);
    __syncthreads();
    const int batch_size = int(smaller<int64_t>(kBlendThreads, hi - batch));
    const int32_t batch_start = int32_t(batch - run_begin);
    for (int chunk = 0; chunk < batch_size; chunk += kWarpSize) {
      if (__all_sync(kFullWarp, done)) break;
      for (unsigned hits = __ballot_sync(kFullWarp, batch_touches_block(sh, chunk + lane, batch_size, at.block));
           hits != 0; hits &= hits - 1) {
        if (done) continue;
        const int j = chunk + __ffs(hits) - 1;
        const ProjectedGaussian<T> g = batch_gaussian(sh, j);
        PairAlpha<T> pair;
        if (!pair_alpha(g, at.px, at.py, pair)) continue;
        const T next = pixel.transmittance * (T(1) - pair.alpha);
        if (next < T(kMinTransmittance)) {
          done = true;
          continue;
        }
        const T weight = pair.alpha * pixel.transmittance;
#pragma unroll
        for (int c = 0; c < kChannels; ++c) pixel.colour[c] += weight * sh.features[c][j];
        pixel.depth += weight * g.depth;
        pixel.transmittance = next;
        pixel.last = batch_start + j + 1;
      }
    }
  }
}

template <typename T, int kChannels>
__device__ void write_pixel(const BlendForwardParams<T>& a, int channel_begin, int channel_count,
                            const BlockPixel<T>& at, const PixelComposite<T, kChannels>& pixel) {
  if (!at.inside) return;
  const int64_t pix = int64_t(at.y) * a.grid.width + at.x;
  T* image = a.b.image + pix * a.channels + channel_begin;
#pragma unroll
  for (int c = 0; c < kChannels; ++c)
    if (c < channel_count) image[c] = pixel.colour[c] + pixel.transmittance * a.background[channel_begin + c];
  if (channel_begin == 0) {
    a.b.alpha[pix] = T(1) - pixel.transmittance;
    a.b.depth_sum[pix] = pixel.depth;
    a.b.depth[pix] = expected_depth_of(pixel.depth, T(1) - pixel.transmittance);
    a.b.final_transmittance[pix] = pixel.transmittance;
    a.b.contributors[pix] = pixel.last;
  }
}

template <int kChannels> __host__ __device__ constexpr int partial_width() { return kChannels + 2; }

// Cuts the runs longer than the cut rule's length (from the pass's own intersection count, which a budgeted pass
// knows only here) into segments, in the blend's tile order (longest first), so that the longest runs' blocks start
// first. One block.
__global__ void __launch_bounds__(kPlanThreads)
    plan_segments_kernel(const int32_t* tile_order, const int64_t* tile_offsets, int64_t tiles, SegmentPlan plan) {
  using Scan = cub::BlockScan<int32_t, kPlanThreads>;
  __shared__ typename Scan::TempStorage scan;
  __shared__ int32_t carried[3];  // segments, partial slots and split tiles of the chunks before
  if (threadIdx.x == 0) carried[0] = carried[1] = carried[2] = 0;
  const int64_t cut_above = plan.cut.longest_uncut(tile_offsets[tiles]);
  __syncthreads();
  for (int64_t chunk = 0; chunk < tiles; chunk += kPlanThreads) {
    const int64_t position = chunk + threadIdx.x;
    int32_t tile = 0, segments = 0;
    int64_t begin = 0, end = 0;
    if (position < tiles) {
      tile = tile_order[position];
      begin = tile_offsets[tile];
      end = tile_offsets[tile + 1];
      const int64_t length = end - begin;
      segments = length > cut_above ? int32_t((length + plan.cut.segment_length - 1) / plan.cut.segment_length) : 1;
    }
    const bool split = segments > 1;
    int32_t first_segment, first_partial, split_index, chunk_segments, chunk_partials, chunk_splits;
    Scan(scan).ExclusiveSum(segments, first_segment, chunk_segments);
    __syncthreads();
    Scan(scan).ExclusiveSum(split ? segments : 0, first_partial, chunk_partials);
    __syncthreads();
    Scan(scan).ExclusiveSum(split ? 1 : 0, split_index, chunk_splits);
    first_segment += carried[0];
    first_partial += carried[1];
    split_index += carried[2];
    if (position < tiles) {
      for (int32_t k = 0; k < segments; ++k) {
        const int64_t segment_begin = begin + k * plan.cut.segment_length;
        plan.segments[first_segment + k] = split ? BlendSegment{tile, split_index, first_partial + k, segment_begin,
                                                                smaller(segment_begin + plan.cut.segment_length, end)}
                                                 : BlendSegment{tile, -1, -1, begin, end};
      }
      if (split) {
        plan.split_tiles[split_index] = SplitTile{tile, first_partial, segments};
        plan.arrivals[split_index] = 0;
      }
    }
    __syncthreads();
    if (threadIdx.x == 0) {
      carried[0] += chunk_segments;
      carried[1] += chunk_partials;
      carried[2] += chunk_splits;
    }
    __syncthreads();
  }
  if (threadIdx.x == 0) *plan.count = carried[0];
}

// One segment's partial composite of one pixel (PartialComposites).
template <typename T, int kChannels> struct PartialPixel {
  T colour[kChannels];
  T transmittance, depth;
  int32_t last;
};

// The partials come from other blocks of this launch: they are read past the (non-coherent) L1 cache.
template <typename T, int kChannels>
__device__ inline PartialPixel<T, kChannels> load_partial(const PartialComposites<T>& partials, int64_t slot) {
  const T* values = partials.values + slot * partial_width<kChannels>();
  PartialPixel<T, kChannels> p;
#pragma unroll
  for (int c = 0; c < kChannels; ++c) p.colour[c] = __ldcg(values + c);
  p.transmittance = __ldcg(values + kChannels);
  p.depth = __ldcg(values + kChannels + 1);
  p.last = __ldcg(partials.last + slot);
  return p;
}

// Joins one pixel of a split tile: its partial composites front to back, up to the segment in which its serial loop
// would stop. A pixel whose loop runs through every segment is written; a pixel that stops inside segment k is handed
// to that segment's block of finish_stopping_segments_kernel: its composite before k replaces k's partial, marked by
// a negative `last`. So the segments in which a tile's pixels stop are composited again at once, by their own
// blocks, not one after another by the joining block (a dense tile's pixels stop in dozens of different segments).
template <typename T, int kChannels>
__device__ __noinline__ void join_segments(const BlendForwardParams<T>& a, int channel_begin, int channel_count,
                                           const BlockPixel<T>& at, const SplitTile& split) {
  if (!at.inside) return;
  PixelComposite<T, kChannels> pixel;
  const int64_t first_slot = int64_t(split.first_partial) * kBlendThreads + threadIdx.x;
  // The next segment's partial is loaded while this one is added: the loop is a chain of reads from L2.
  PartialPixel<T, kChannels> next = load_partial<T, kChannels>(a.partials, first_slot);
  for (int32_t k = 0; k < split.segments; ++k) {
    const PartialPixel<T, kChannels> segment = next;
    if (k + 1 < split.segments)
      next = load_partial<T, kChannels>(a.partials, first_slot + int64_t(k + 1) * kBlendThreads);
    if (segment.transmittance < T(0) && pixel.transmittance == T(1)) {
      // Nothing blended before the segment: its own composite is the serial loop's, stop included.
#pragma unroll
      for (int c = 0; c < kChannels; ++c) pixel.colour[c] = segment.colour[c];
      pixel.depth = segment.depth;
      pixel.transmittance = -segment.transmittance;
      pixel.last = segment.last;
      break;
    }
    if (segment.transmittance < T(0) || pixel.transmittance * segment.transmittance < T(kMinTransmittance)) {
      const int64_t slot = first_slot + int64_t(k) * kBlendThreads;
      T* values = a.partials.values + slot * partial_width<kChannels>();
#pragma unroll
      for (int c = 0; c < kChannels; ++c) values[c] = pixel.colour[c];
      values[kChannels] = pixel.transmittance;
      values[kChannels + 1] = pixel.depth;
      a.partials.last[slot] = -1 - pixel.last;
      return;
    }
#pragma unroll
    for (int c = 0; c < kChannels; ++c) pixel.colour[c] += pixel.transmittance * segment.colour[c];
    pixel.depth += pixel.transmittance * segment.depth;
    pixel.transmittance *= segment.transmittance;
    if (segment.last > 0) pixel.last = segment.last;
  }
  write_pixel(a, channel_begin, channel_count, at, pixel);
}

// One block per segment of the plan: a whole run writes its pixels; a segment of a split tile writes its partial
// composite, and the tile's last segment to finish joins them, while other tiles' blocks still run.
template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads, kForwardBlendBlocks<T>)
    blend_forward_kernel(const __grid_constant__ BlendForwardParams<T> a, int channel_begin, int channel_count) {
  __shared__ ForwardShared<T, kChannels> sh;
  __shared__ bool joins;
  if (int32_t(blockIdx.x) >= *a.plan.count) return;
  const BlendSegment segment = a.plan.segments[blockIdx.x];
  const BlockPixel<T> at = block_pixel<T>(segment.tile, a.grid);
  PixelComposite<T, kChannels> pixel;
  bool done = !at.inside;
  composite_run(sh, a, channel_begin, channel_count, at, a.b.tile_offsets[segment.tile], segment.begin, segment.end,
                pixel, done);
  if (segment.split < 0) {
    write_pixel(a, channel_begin, channel_count, at, pixel);
    return;
  }
  const int64_t slot = int64_t(segment.slot) * kBlendThreads + threadIdx.x;
  T* values = a.partials.values + slot * partial_width<kChannels>();
#pragma unroll
  for (int c = 0; c < kChannels; ++c) values[c] = pixel.colour[c];
  values[kChannels] = done && at.inside ? -pixel.transmittance : pixel.transmittance;
  values[kChannels + 1] = pixel.depth;
  a.partials.last[slot] = pixel.last;
  // The barrier orders the block's partial before thread 0's fence and count, as a grid barrier does; the fence
  // after the count orders the joining block's reads after it.
  __syncthreads();
  const SplitTile split = a.plan.split_tiles[segment.split];
  if (threadIdx.x == 0) {
    __threadfence();
    joins = atomicAdd(a.plan.arrivals + segment.split, 1) == split.segments - 1;
    __threadfence();
  }
  __syncthreads();
  if (joins) join_segments<T, kChannels>(a, channel_begin, channel_count, at, split);
}

// After blend_forward_kernel, one block per segment of the plan: the pixels that join_segments handed to a split
// tile's segment composite it again from their true transmittance with the serial loop's stop rule, and on into
// the rest of the run should rounding let one pass the segment's end (the product of the segments' transmittances
// may fall below the threshold where the serial loop's own products do not), then are written.
template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads, kForwardBlendBlocks<T>)
    finish_stopping_segments_kernel(const __grid_constant__ BlendForwardParams<T> a, int channel_begin,
                                    int channel_count) {
  __shared__ ForwardShared<T, kChannels> sh;
  if (int32_t(blockIdx.x) >= *a.plan.count) return;
  const BlendSegment segment = a.plan.segments[blockIdx.x];
  if (segment.split < 0) return;
  const BlockPixel<T> at = block_pixel<T>(segment.tile, a.grid);
  PixelComposite<T, kChannels> pixel;
  bool done = true;
  if (at.inside) {
    const int64_t slot = int64_t(segment.slot) * kBlendThreads + threadIdx.x;
    const int32_t last = a.partials.last[slot];
    if (last < 0) {
      const T* values = a.partials.values + slot * partial_width<kChannels>();
#pragma unroll
      for (int c = 0; c < kChannels; ++c) pixel.colour[c] = values[c];
      pixel.transmittance = values[kChannels];
      pixel.depth = values[kChannels + 1];
      pixel.last = -1 - last;
      done = false;
    }
  }
  const bool handed = !done;
  if (__syncthreads_count(handed) == 0) return;
  const int64_t run_begin = a.b.tile_offsets[segment.tile], run_end = a.b.tile_offsets[segment.tile + 1];
  composite_run(sh, a, channel_begin, channel_count, at, run_begin, segment.begin, run_end, pixel, done);
  if (handed) write_pixel(a, channel_begin, channel_count, at, pixel);
}

// One block per tile, in the blend's tile order: the pass when no run is cut, with neither a plan to read nor a join
// to call (whose call frame costs the segmented kernel stack traffic).
template <typename T, int kChannels>
__global__ void __launch_bounds__(kBlendThreads, kForwardBlendBlocks<T>)
    blend_whole_tiles_kernel(const __grid_constant__ BlendForwardParams<T> a, int channel_begin, int channel_count) {
  __shared__ ForwardShared<T, kChannels> sh;
  const int tile = a.b.tile_order[blockIdx.x];
  const BlockPixel<T> at = block_pixel<T>(tile, a.grid);
  PixelComposite<T, kChannels> pixel;
  bool done = !at.inside;
  const int64_t begin = a.b.tile_offsets[tile];
  composite_run(sh, a, channel_begin, channel_count, at, begin, begin, a.b.tile_offsets[tile + 1], pixel, done);
  write_pixel(a, channel_begin, channel_count, at, pixel);
}

template <typename T> CutRule cut_rule(int64_t segment_length) {
  int device = 0, processors = 0;
  check_cuda(cudaGetDevice(&device), "cudaGetDevice");
  check_cuda(cudaDeviceGetAttribute(&processors, cudaDevAttrMultiProcessorCount, device), "multiprocessor count");
  return CutRule{segment_length, int64_t(processors) * kForwardBlendBlocks<T>, blend_cut_share()};
}

template <typename T> void blend_whole_tiles(const BlendForwardParams<T>& params, int64_t tiles, cudaStream_t stream) {
  record_blend_path(BlendPath::kWholeTiles);
  if (tiles == 0) return;
  for_each_channel_chunk(params.channels, [&](auto width, int channel_begin, int channel_count) {
    blend_whole_tiles_kernel<T, decltype(width)::value>
        <<<unsigned(tiles), kBlendThreads, 0, stream>>>(params, channel_begin, channel_count);
    check_cuda(cudaGetLastError(), "blend_whole_tiles_kernel launch");
  });
}

}  // namespace

template <typename T>
void blend(const SplatScene<T>& s, const ForwardBuffers<T>& b, const BinStats& stats, bool stats_exact,
           const ScratchAllocator& scratch, cudaStream_t stream) {
  const Stage stage("blend", stream);
  const TileGrid grid = grid_of(s);
  const int64_t tiles = tile_count(grid);
  BlendForwardParams<T> params{b, s.features, s.background, s.channels, grid, {}, {}};
  const int64_t length = blend_segment_length();
  if (length <= 0) return blend_whole_tiles(params, tiles, stream);
  // A budget bounds the longest run but not the intersections below it, so only the pass's own count tells the
  // host that the plan would cut nothing.
  const CutRule cut = cut_rule<T>(length);
  if (stats.max_tile_length <= (stats_exact ? cut.longest_uncut(stats.intersections) : length))
    return blend_whole_tiles(params, tiles, stream);
  record_blend_path(BlendPath::kSegmented);
  // A run of n > length intersections takes ceil(n / length) < n / length + 1 segments and partial slots, and a tile
  // is split only when n > length: at most intersections / length split tiles, 2 intersections / length slots.
  const int64_t most_split = stats.intersections / length;
  const int64_t most_segments = tiles + most_split;
  if (most_segments > int64_t(INT32_MAX))
    throw std::runtime_error("sfgs CUDA backend: the blend's segments exceed 2^31 - 1");
  params.plan = SegmentPlan{allocate<BlendSegment>(scratch, most_segments), allocate<SplitTile>(scratch, most_split),
                            allocate<int32_t>(scratch, most_split), allocate<int32_t>(scratch, 1), cut};
  const int64_t chunk_channels = s.channels < kMaxChunkChannels ? s.channels : kMaxChunkChannels;
  params.partials = PartialComposites<T>{allocate<T>(scratch, 2 * most_split * kBlendThreads * (chunk_channels + 2)),
                                         allocate<int32_t>(scratch, 2 * most_split * kBlendThreads)};
  plan_segments_kernel<<<1, kPlanThreads, 0, stream>>>(b.tile_order, b.tile_offsets, tiles, params.plan);
  check_cuda(cudaGetLastError(), "plan_segments_kernel launch");
  for_each_channel_chunk(s.channels, [&](auto width, int channel_begin, int channel_count) {
    if (channel_begin > 0 && most_split > 0) {
      // Each chunk counts its own arrivals.
      check_cuda(cudaMemsetAsync(params.plan.arrivals, 0, sizeof(int32_t) * most_split, stream), "arrivals reset");
    }
    blend_forward_kernel<T, decltype(width)::value>
        <<<unsigned(most_segments), kBlendThreads, 0, stream>>>(params, channel_begin, channel_count);
    check_cuda(cudaGetLastError(), "blend_forward_kernel launch");
    finish_stopping_segments_kernel<T, decltype(width)::value>
        <<<unsigned(most_segments), kBlendThreads, 0, stream>>>(params, channel_begin, channel_count);
    check_cuda(cudaGetLastError(), "finish_stopping_segments_kernel launch");
  });
}

template void blend<float>(const SplatScene<float>&, const ForwardBuffers<float>&, const BinStats&, bool,
                           const ScratchAllocator&, cudaStream_t);
template void blend<double>(const SplatScene<double>&, const ForwardBuffers<double>&, const BinStats&, bool,
                            const ScratchAllocator&, cudaStream_t);

}  // namespace sfgs::splat::cuda_kernels
