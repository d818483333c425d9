#include "train/step_graphs.h"

#include <algorithm>

#include <ATen/ATen.h>

#include "train/constants.h"
#include "ops/splat/splat.h"

namespace sfgs::train {

namespace {

static_assert(kGraphUncheckedSteps >= 1, "the host reads a step's counts after queuing at least that step");

at::Device recordable(at::Device device) {
  TORCH_CHECK(device.is_cuda() && device_graphs_available(),
              "StepGraphs: recording training steps needs a CUDA device and a CUDA build, got ", device);
  return device;
}

}  // namespace

StepGraphs::StepGraphs(model::Avatar avatar, at::Device device, double budget_slack)
    : avatar_(std::move(avatar)), device_(recordable(device)), budget_(device_, budget_slack, "training") {}

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
  // The steps queued before the previous one are done by now (the GPU is on the previous one): read their counts.
  while (pending_.size() >= size_t(kGraphUncheckedSteps)) check_oldest();
  for (;;) {
    if (!budget_.measured()) {
      // No step has measured the splatting yet: an eager step with a guess. If it fitted, it is this step.
      StepOutputs eager = run_budgeted(kind, work);
      const BinningCounts counts = budget_.read();
      const bool fitted = budget_.fits(counts);
      budget_.grow(counts);
      if (fitted) {
        ++stats_.eager_steps;
        return eager;
      }
      continue;
    }
    if (!kind.graph) capture(kind, work);
    kind.graph->replay();
    ++stats_.replays;
    break;
  }
  StepOutputs outputs = kind.outputs;
  outputs.skip_update = queue_check();
  const std::vector<at::Tensor> parameters = avatar_->parameters();
  for (size_t k = 0; k < parameters.size(); ++k) parameters[k].mutable_grad() = kind.gradients[k];
  return outputs;
}

void StepGraphs::settle() {
  while (!pending_.empty()) check_oldest();
}

at::Tensor StepGraphs::queue_check() {
  PendingCheck check;
  check.counts = at::empty({BinningBudget::kCounts}, at::TensorOptions().dtype(at::kLong).pinned_memory(true));
  check.counts.copy_(budget_.device_counts(), /*non_blocking=*/true);
  check.copied = record_device_event();
  pending_.push_back(std::move(check));
  return budget_.overflowed();
}

void StepGraphs::check_oldest() {
  PendingCheck oldest = std::move(pending_.front());
  pending_.pop_front();
  oldest.copied->wait();
  BinningCounts largest = budget_.counts_from(oldest.counts);
  if (budget_.fits(largest)) return;
  // That step rendered an incomplete image (the optimiser left it out). The steps queued after it ran under the same
  // budget: read them too, grow the budget past all of them, and record the graphs again before the next step.
  ++stats_.budget_overflows;
  for (PendingCheck& later : pending_) {
    later.copied->wait();
    const BinningCounts counts = budget_.counts_from(later.counts);
    if (!budget_.fits(counts)) ++stats_.budget_overflows;
    largest.intersections = std::max(largest.intersections, counts.intersections);
    largest.longest_tile = std::max(largest.longest_tile, counts.longest_tile);
  }
  pending_.clear();
  budget_.grow(largest);
  // The previous step's replay may still run: the graphs (and their pool) go only once it is done. One wait per
  // overflow, a handful in a run.
  record_device_event()->wait();
  drop_graphs();
}

StepOutputs StepGraphs::run_budgeted(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work) {
  // The budget only for this step: the same inputs may later run a step eagerly, which must read its count.
  struct BudgetForThisStep {
    StepInputs& inputs;
    ~BudgetForThisStep() { inputs.budget.reset(); }
  } scope{*kind.inputs};
  kind.inputs->budget = budget_.budget(avatar_->gaussian_count());
  return work(*kind.inputs);
}

void StepGraphs::capture(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work) {
  // Every graph records into the first one's pool: steps never run at once, and each graph keeps its outputs and
  // gradients (the tensors its replays write) alive as long as it lives (device_graph.h).
  DeviceGraph* pool = nullptr;
  for (auto& [name, other] : kinds_)
    if (other.graph) pool = other.graph.get();
  StepOutputs recorded;
  try {
    kind.graph = capture_device_graph([&] { recorded = run_budgeted(kind, work); }, pool);
  } catch (const GraphCaptureError& e) {
    drop_graphs();
    throw StepRecordingError(std::string("a training step could not be recorded as a CUDA graph: ") + e.what());
  }
  kind.outputs = std::move(recorded);
  kind.gradients.clear();
  for (const at::Tensor& p : avatar_->parameters()) kind.gradients.push_back(p.grad());
  ++stats_.captures;
  stats_.intersection_budget = budget_.intersections();
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

}  // namespace sfgs::train
