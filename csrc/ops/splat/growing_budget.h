#pragma once
// The splatting budget of recorded work (splat.h, BinningBudget) grown from the counts its passes report: the
// Animator's frames and the trainer's recorded steps size their intersection buffers from one of these. Until a pass
// is measured the budget is a first guess per Gaussian; each pass's true counts are read back once its work is done,
// and a pass beyond the budget (which rendered only the background) grows it, with slack, to be recorded again.
#include <cstdint>
#include <string>

#include <ATen/core/Tensor.h>

#include "ops/splat/splat.h"

namespace sfgs {

// What a budgeted pass reports (BinningBudget::counts).
struct BinningCounts {
  int64_t intersections = 0;
  int64_t longest_tile = 0;       // Gaussians in the busiest tile
  int64_t invalid_opacities = 0;  // non-finite or outside [0, 1]: the pass rendered only the background
};

class GrowingBudget {
 public:
  // `slack` >= 1: the headroom over the counts of the pass the budget is taken from; `owner` names the caller in
  // errors.
  GrowingBudget(at::Device device, double slack, std::string owner);

  // The budget to render with (RenderOptions::budget) for `gaussians` Gaussians: a first guess until a pass is
  // measured.
  BinningBudget budget(int64_t gaussians);
  bool measured() const { return measured_; }
  int64_t intersections() const { return intersections_; }

  // The counts of the latest pass under budget(); waits for its work. A pass with invalid opacities is an error.
  BinningCounts read() const;
  // The counts as the device holds them (BinningBudget::kCounts int64), for a copy the host reads later, and that
  // copy's counts (the same check as read()).
  const at::Tensor& device_counts() const { return counts_; }
  BinningCounts counts_from(const at::Tensor& host_counts) const;
  // 0-dim float on the device: 1 where the latest pass went beyond the current budget or met invalid opacities,
  // else 0 (no host read: the optimiser's skip flag).
  at::Tensor overflowed() const;
  bool fits(const BinningCounts& counts) const;
  // Sizes the budget from `counts` with the slack: the first measured pass replaces the guess, later ones only grow it.
  void grow(const BinningCounts& counts);

 private:
  double slack_;
  std::string owner_;
  at::Tensor counts_;          // BinningBudget::kCounts int64 on the device
  mutable at::Tensor limits_;  // (intersections, longest tile, 0 invalid opacities) on the device, for overflowed()
  mutable int64_t limits_intersections_ = -1, limits_longest_tile_ = -1;
  int64_t intersections_ = 0, longest_tile_ = 0;
  bool measured_ = false;
};

}  // namespace sfgs
