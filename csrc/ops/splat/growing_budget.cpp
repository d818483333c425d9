#include "ops/splat/growing_budget.h"

#include <algorithm>
#include <cmath>

#include <ATen/ATen.h>

#include "ops/splat/constants.h"

namespace sfgs {

GrowingBudget::GrowingBudget(at::Device device, double slack, std::string owner)
    : slack_(slack), owner_(std::move(owner)) {
  TORCH_CHECK(slack_ >= 1 && std::isfinite(slack_), owner_, ": the budget slack must be a finite number >= 1, got ",
              slack_);
  TORCH_CHECK(device.is_cuda(), owner_, ": a splatting budget is for CUDA renders, got ", device);
  counts_ = at::zeros({BinningBudget::kCounts}, at::TensorOptions(device).dtype(at::kLong));
}

BinningBudget GrowingBudget::budget(int64_t gaussians) {
  if (!measured_ && intersections_ == 0)
    intersections_ = longest_tile_ = std::max<int64_t>(1, gaussians * kGraphInitialIntersectionsPerGaussian);
  return BinningBudget{intersections_, longest_tile_, counts_};
}

BinningCounts GrowingBudget::read() const {
  return counts_from(counts_.cpu());  // waits for the pass
}

at::Tensor GrowingBudget::overflowed() const {
  if (!limits_.defined() || limits_intersections_ != intersections_ || limits_longest_tile_ != longest_tile_) {
    // Uploaded when the budget changes (never while a graph is being recorded: budgets change between steps).
    limits_ = at::tensor({intersections_, longest_tile_, int64_t(0)}, at::kLong).to(counts_.device());
    limits_intersections_ = intersections_;
    limits_longest_tile_ = longest_tile_;
  }
  return at::gt(counts_, limits_).any().to(at::kFloat);
}

BinningCounts GrowingBudget::counts_from(const at::Tensor& host_counts) const {
  const at::Tensor host = host_counts.contiguous();
  const int64_t* v = host.data_ptr<int64_t>();
  const BinningCounts counts{v[0], v[1], v[2]};
  TORCH_CHECK(counts.invalid_opacities == 0, owner_, ": ", counts.invalid_opacities,
              " opacities of the posed avatar are not finite or outside [0, 1]");
  return counts;
}

bool GrowingBudget::fits(const BinningCounts& counts) const {
  return counts.intersections <= intersections_ && counts.longest_tile <= longest_tile_;
}

void GrowingBudget::grow(const BinningCounts& counts) {
  int64_t intersections = std::max<int64_t>(1, std::llround(double(counts.intersections) * slack_));
  int64_t longest_tile = std::max<int64_t>(1, std::llround(double(counts.longest_tile) * slack_));
  if (measured_) {
    // A pass beyond one bound keeps the other: passes that alternate between many intersections and one busy tile
    // would otherwise record again at every turn.
    intersections = std::max(intersections, intersections_);
    longest_tile = std::max(longest_tile, longest_tile_);
  }
  intersections_ = intersections;
  longest_tile_ = longest_tile;
  measured_ = true;
}

}  // namespace sfgs
