#pragma once
// One range of a benchmark for Nsight Compute: run under `ncu --profile-from-start off --nvtx`, only the kernels
// launched inside a ProfiledRange are profiled, and the range and every stage inside it (StageScope) are NVTX
// ranges, so that `--print-nvtx-rename kernel` or `--print-summary per-nvtx` attribute each kernel to its stage.
// Kernels launched by other threads (the autograd engine's backward) carry no stage range. Without CUDA it does
// nothing.
#include <torch/cuda.h>

#include "common/stage_timer.h"
#if defined(SFGS_WITH_CUDA)
#include <nvtx3/nvToolsExt.h>

#include "ops/splat/cuda/diagnostics.h"
#endif

namespace sfgs::bench {

// StageScopes as NVTX push / pop ranges of the calling thread.
class NvtxStages : public StageRecorder {
 public:
  void begin(const char* stage) override {
#if defined(SFGS_WITH_CUDA)
    nvtxRangePushA(stage);
#endif
  }
  void end(const char*) override {
#if defined(SFGS_WITH_CUDA)
    nvtxRangePop();
#endif
  }
};

// Starts and stops the profiler's collection (the device idle at both ends) around an NVTX range `name`. Stages
// inside it become NVTX ranges where the caller installs NvtxStages.
class ProfiledRange {
 public:
  explicit ProfiledRange(const char* name) {
    torch::cuda::synchronize();
#if defined(SFGS_WITH_CUDA)
    splat::cuda_kernels::set_profiler_capture(true);
#endif
    NvtxStages().begin(name);
  }
  ~ProfiledRange() {
    torch::cuda::synchronize();
    NvtxStages().end(nullptr);
#if defined(SFGS_WITH_CUDA)
    splat::cuda_kernels::set_profiler_capture(false);
#endif
  }
  ProfiledRange(const ProfiledRange&) = delete;
  ProfiledRange& operator=(const ProfiledRange&) = delete;
};

}  // namespace sfgs::bench
