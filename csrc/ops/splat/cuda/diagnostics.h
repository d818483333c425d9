#pragma once
// Switches and hooks of the CUDA kernels for tests and benchmarks: they force a binning path, a tile order or a blend
// cut rule, report the path taken, and let a benchmark time each stage. The op uses only their defaults. Global, not
// thread-safe.
#include <cstdint>

#include <cuda_runtime_api.h>
#include "ops/splat/constants.h"

namespace sfgs {

// The forward blend cuts runs longer than kBlendSegmentLength (common/constants.h) into segments, but only a run
// longer than this many times the pass's intersections per resident blend block (multiprocessors times the blocks
// one holds): with the tiles taken longest first, a run that long is still being composited when
// the other blocks have shared out the rest of the pass, so it sets the pass's length and cutting it pays. Cutting a
// shorter run only costs: each segment composites its whole share even where the pixels' transmittance ran out in an
// earlier one (a dense scene's tiles saturate early): cutting every run longer than a segment doubles the generic
// benchmark's forward. 1.5 leaves the generic benchmark's densest runs (about one share, by an
// estimate from its scene) whole with a margin, and cuts the trained avatar's runs beyond about 600 (324,646
// intersections at 800x1200 on the H200's 132 x 6 blocks); bench_splat_cuda's cut-rule table and bench_animate
// --blend-cut-shares measure it (docs/performance.md).
inline constexpr double kBlendCutShare = 1.5;

}  // namespace sfgs

namespace sfgs::splat::cuda_kernels {

// Which binning path bin_intersections takes: the per-tile shared-memory sort when every tile fits it (kAuto), or
// always the radix path (kRadix), for tests and benchmarks that compare the two.
enum class Binning { kAuto, kRadix };
void set_binning(Binning binning);
// The path the latest bin_intersections call took (kAuto: the per-tile sort).
Binning last_binning();

// The order in which the blends take the tiles: longest runs first (the default), or row-major, for benchmarks that
// measure what the ordering gains.
enum class TileOrder { kLongestFirst, kRowMajor };
void set_tile_order(TileOrder order);

// The length of the segments into which the forward blend cuts a long run, for several blocks to composite at once
// (default kBlendSegmentLength); 0 never cuts. For tests that compare the two and benchmarks that tune it.
void set_blend_segment_length(int64_t length);
// The forward blend cuts only the runs longer than `share` times the pass's intersections per resident block (default
// kBlendCutShare); 0 cuts every run longer than a segment. For tests of the cut path and benchmarks that tune it.
void set_blend_cut_share(double share);
// The kernel the latest forward blend ran: one block per tile with no run cut (the host saw that none would be), or
// the segmented kernel after the device's plan (which may still cut none, in a budgeted pass).
enum class BlendPath { kWholeTiles, kSegmented };
BlendPath last_blend_path();

// Benchmarks time the pipeline's stages by recording their own events when these are called; the stages are named
// "project", "emit", "tile sort", "blend", "blend backward" and "project backward", and on the radix path
// "depth sort" and "tile ranges" too.
class StageObserver {
 public:
  virtual void begin(const char* stage, cudaStream_t stream) = 0;
  virtual void end(const char* stage, cudaStream_t stream) = 0;

 protected:
  ~StageObserver() = default;
};
// Installs the observer for all later calls on every thread (null removes it).
void set_stage_observer(StageObserver* observer);

// Starts (true) or stops (false) the profiler's collection (cudaProfilerStart / Stop): under
// `ncu --profile-from-start off` only the kernels launched in between are profiled, so a benchmark can profile one
// frame or one training step after its warm-up.
void set_profiler_capture(bool capture);

}  // namespace sfgs::splat::cuda_kernels
