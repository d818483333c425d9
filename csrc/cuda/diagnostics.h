#pragma once
// Switches and hooks of the CUDA kernels for tests and benchmarks only: they force a binning path or a tile order,
// report the path taken, and let a benchmark time each stage. The op never uses them. Global, not thread-safe.
#include <cstdint>

#include <cuda_runtime_api.h>

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
