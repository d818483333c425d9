// The state behind diagnostics.h, read by the stages through kernel_common.cuh.
#include <cuda_profiler_api.h>

#include "ops/splat/cuda/kernel_common.cuh"
#include "ops/splat/constants.h"

namespace sfgs::splat::cuda_kernels {
namespace {

StageObserver* g_stage_observer = nullptr;
Binning g_binning = Binning::kAuto;
Binning g_last_binning = Binning::kAuto;
TileOrder g_tile_order = TileOrder::kLongestFirst;
int64_t g_blend_segment_length = kBlendSegmentLength;
double g_blend_cut_share = kBlendCutShare;
BlendPath g_last_blend_path = BlendPath::kWholeTiles;

}  // namespace

void set_stage_observer(StageObserver* observer) { g_stage_observer = observer; }
void set_binning(Binning binning) { g_binning = binning; }
Binning last_binning() { return g_last_binning; }
void set_tile_order(TileOrder order) { g_tile_order = order; }
void set_blend_segment_length(int64_t length) { g_blend_segment_length = length; }
void set_blend_cut_share(double share) { g_blend_cut_share = share; }
BlendPath last_blend_path() { return g_last_blend_path; }
void set_profiler_capture(bool capture) {
  // Without a profiler attached both calls do nothing; their status is not worth failing a benchmark over.
  (void)(capture ? cudaProfilerStart() : cudaProfilerStop());
}

StageObserver* stage_observer() { return g_stage_observer; }
Binning requested_binning() { return g_binning; }
void record_binning(Binning taken) { g_last_binning = taken; }
TileOrder tile_order() { return g_tile_order; }
int64_t blend_segment_length() { return g_blend_segment_length; }
double blend_cut_share() { return g_blend_cut_share; }
void record_blend_path(BlendPath taken) { g_last_blend_path = taken; }

}  // namespace sfgs::splat::cuda_kernels
