#pragma once
// CUDA training steps recorded as graphs and replayed (common/device_graph.h): a step's thousand-odd launches
// become one, and the host no longer paces the GPU. One graph per kind of step (train/training_step.h, step_kind:
// with or without the time branch or LPIPS, frame size, pose layout, camera intrinsics), all in one memory pool;
// each graph keeps its outputs and the parameters' gradients, which the trainer reads after a replay (the optimiser
// runs outside the graphs, so learning rates and step counts stay host values).
//
// The splatting's intersection buffers are sized from a budget (splat.h, BinningBudget) instead of the count read
// that a graph cannot hold. Each replay's true counts are read back once the step is done (the step's one host
// synchronisation, before the optimiser): a step beyond the budget grows it, records the graphs again and runs
// again, so no step ever trains on an incomplete image. While no budget is known, steps run eagerly with a guess.
#include <array>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

#include "common/constants.h"
#include "common/device_graph.h"
#include "model/avatar.h"
#include "train/training_step.h"

namespace sfgs::train {

struct StepGraphStats {
  int64_t captures = 0;          // graphs recorded (a new kind of step, or a grown budget)
  int64_t replays = 0;           // steps run as one replay (those that overflowed included)
  int64_t eager_steps = 0;       // steps run eagerly while the budget was unknown
  int64_t budget_overflows = 0;  // replays that reported more intersections than their budget, and ran again
  int64_t intersection_budget = 0;
};

class StepGraphs {
 public:
  // The step is the avatar's (its parameters receive the gradients); budget_slack >= 1 is the headroom of the
  // splatting budget over the counts of the step it was taken from.
  StepGraphs(model::Avatar avatar, at::Device device, double budget_slack = kGraphBudgetSlack);
  ~StepGraphs();
  StepGraphs(const StepGraphs&) = delete;
  StepGraphs& operator=(const StepGraphs&) = delete;

  // One step on `data`: `work` (the step's device work on the inputs it is given, TrainingStep::run) replayed from
  // the graph of the data's kind, recorded first if there is none. On return the parameters' gradients are the
  // step's and the outputs are on the device; they stay valid until the next run().
  StepOutputs run(const StepData& data, const std::function<StepOutputs(const StepInputs&)>& work);
  const StepGraphStats& stats() const { return stats_; }

 private:
  struct Kind {
    std::unique_ptr<StepInputs> inputs;
    std::unique_ptr<DeviceGraph> graph;
    StepOutputs outputs;                // the graph's, rewritten by each replay
    std::vector<at::Tensor> gradients;  // the graph's, per parameter (undefined: the kind does not reach it)
  };
  StepOutputs run_budgeted(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work);
  void capture(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work);
  void drop_graphs();
  std::array<int64_t, 3> read_counts() const;
  bool fits(const std::array<int64_t, 3>& counts) const;
  void grow_budget(const std::array<int64_t, 3>& counts);

  model::Avatar avatar_;
  at::Device device_;
  double budget_slack_;
  std::map<std::string, Kind> kinds_;
  at::Tensor counts_;  // BinningBudget::kCounts on the device
  int64_t intersection_budget_ = 0, tile_budget_ = 0;
  bool budget_measured_ = false;
  StepGraphStats stats_;
};

}  // namespace sfgs::train
