#include "train/step_graphs.h"

#include <algorithm>
#include <cmath>

#include <ATen/ATen.h>

#include "splat/splat.h"

namespace sfgs::train {

StepGraphs::StepGraphs(model::Avatar avatar, at::Device device, double budget_slack)
    : avatar_(std::move(avatar)), device_(device), budget_slack_(budget_slack) {
  TORCH_CHECK(device_.is_cuda() && device_graphs_available(),
              "StepGraphs: recording training steps needs a CUDA device and a CUDA build, got ", device_);
  TORCH_CHECK(budget_slack_ >= 1 && std::isfinite(budget_slack_),
              "StepGraphs: budget_slack must be a finite number >= 1, got ", budget_slack_);
  counts_ = at::zeros({BinningBudget::kCounts}, at::TensorOptions(device_).dtype(at::kLong));
}

StepGraphs::~StepGraphs() = default;

StepOutputs StepGraphs::run(const StepData& data, const std::function<StepOutputs(const StepInputs&)>& work) {
  const std::string name = step_kind(data);
  auto found = kinds_.find(name);
  if (found == kinds_.end()) {
    Kind fresh;
    fresh.inputs = std::make_unique<StepInputs>(data, device_);
    found = kinds_.emplace(name, std::move(fresh)).first;
  }
  Kind& kind = found->second;
  kind.inputs->upload(data);
  for (;;) {
    if (!budget_measured_) {
      // No step has measured the splatting yet: an eager step with a guess (which also makes every lazy one-time
      // allocation outside the graphs). If it fitted, it is this step.
      if (intersection_budget_ == 0)
        intersection_budget_ = tile_budget_ =
            std::max<int64_t>(1, avatar_->gaussian_count() * kGraphInitialIntersectionsPerGaussian);
      StepOutputs eager = run_budgeted(kind, work);
      const std::array<int64_t, 3> counts = read_counts();
      const bool fitted = fits(counts);
      grow_budget(counts);
      budget_measured_ = true;
      if (fitted) {
        ++stats_.eager_steps;
        return eager;
      }
      continue;
    }
    if (!kind.graph) capture(kind, work);
    kind.graph->replay();
    ++stats_.replays;
    const std::array<int64_t, 3> counts = read_counts();  // waits for the step
    if (fits(counts)) break;
    // The step's image was emptied on the device: grow the budget, record again, and run the same step.
    ++stats_.budget_overflows;
    grow_budget(counts);
    drop_graphs();
  }
  const std::vector<at::Tensor> parameters = avatar_->parameters();
  for (size_t k = 0; k < parameters.size(); ++k) parameters[k].mutable_grad() = kind.gradients[k];
  return kind.outputs;
}

StepOutputs StepGraphs::run_budgeted(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work) {
  const ScopedBinningBudget budget(BinningBudget{intersection_budget_, tile_budget_, counts_});
  return work(*kind.inputs);
}

void StepGraphs::capture(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work) {
  // Every graph records into the first one's pool: steps never run at once, and each graph keeps its outputs and
  // gradients (the tensors its replays write) alive as long as it lives (device_graph.h).
  DeviceGraph* pool = nullptr;
  for (const auto& [name, other] : kinds_)
    if (other.graph) pool = other.graph.get();
  StepOutputs recorded;
  kind.graph = capture_device_graph([&] { recorded = run_budgeted(kind, work); }, pool);
  kind.outputs = std::move(recorded);
  kind.gradients.clear();
  for (const at::Tensor& p : avatar_->parameters()) kind.gradients.push_back(p.grad());
  ++stats_.captures;
  stats_.intersection_budget = intersection_budget_;
}

void StepGraphs::drop_graphs() {
  // Every reference into the graphs' pool goes, the parameters' gradients included, so the next capture's release of
  // cached memory returns the pool to the driver.
  for (at::Tensor& p : avatar_->parameters()) p.mutable_grad().reset();
  for (auto& [name, kind] : kinds_) {
    kind.graph.reset();
    kind.outputs = StepOutputs();
    kind.gradients.clear();
  }
}

std::array<int64_t, 3> StepGraphs::read_counts() const {
  const at::Tensor host = counts_.cpu();
  const int64_t* v = host.data_ptr<int64_t>();
  return {v[0], v[1], v[2]};
}

bool StepGraphs::fits(const std::array<int64_t, 3>& counts) const {
  TORCH_CHECK(counts[2] == 0, "training: ", counts[2],
              " opacities of the posed avatar are not finite or outside [0, 1]");
  return counts[0] <= intersection_budget_ && counts[1] <= tile_budget_;
}

void StepGraphs::grow_budget(const std::array<int64_t, 3>& counts) {
  intersection_budget_ = std::max<int64_t>(1, std::llround(double(counts[0]) * budget_slack_));
  tile_budget_ = std::max<int64_t>(1, std::llround(double(counts[1]) * budget_slack_));
}

}  // namespace sfgs::train
