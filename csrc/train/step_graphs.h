#pragma once
// CUDA training steps recorded as graphs and replayed (common/device_graph.h): a step's thousand-odd launches
// become one, and the host no longer paces the GPU. One graph per kind of step (train/training_step.h, step_kind:
// with or without the time branch or LPIPS, frame size, pose layout, camera intrinsics), all in one memory pool;
// each graph keeps its outputs and the parameters' gradients, which the trainer reads after a replay (the optimiser
// runs outside the graphs, so learning rates and step counts stay host values).
//
// The splatting's intersection buffers are sized from a budget (ops/splat/growing_budget.h) instead of the count read
// that a graph cannot hold, and the host never waits for a replayed step: each replay's true counts are copied to
// page-locked memory in stream order and read two steps later, when that step has long finished (a DeviceEvent, not
// a wait for the queue). A step beyond its budget rendered an incomplete image, so its outputs carry skip_update = 1
// (computed on the device) and the optimiser leaves it out; once the host reads its counts, the budget grows and the
// graphs are recorded again (the step after it, replayed before the host knew, is left out likewise if it
// overflowed too). While no budget is known, steps run eagerly with a guess and are read at once.
//
// Contract: a step's outputs (and the gradients it leaves on the parameters) are valid until the next run(); the
// graphs share one pool, so another kind's replay may overwrite them: copy what must last (the trainer does: the
// loss watch stacks the terms, LPIPS is cloned). The avatar must stay as it was (parameters are updated in place; the
// planes' reads and every buffer a graph reads keep their addresses); moving it needs a new StepGraphs.
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

#include "ops/splat/constants.h"
#include "common/device_graph.h"
#include "model/avatar.h"
#include "ops/splat/growing_budget.h"
#include "train/training_step.h"

namespace sfgs::train {

// A step could not be recorded (it synchronises with the host, or reads host memory): the caller runs it, and the
// rest, eagerly.
class StepRecordingError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct StepGraphStats {
  int64_t captures = 0;          // graphs recorded (a new kind of step, or a grown budget)
  int64_t replays = 0;           // steps run as one replay (those that overflowed included)
  int64_t eager_steps = 0;       // steps run eagerly while the budget was unknown
  int64_t budget_overflows = 0;  // replays beyond their budget (skipped by the optimiser; the budget then grew)
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
  // step's and the outputs are on the device; they stay valid until the next run(). Throws StepRecordingError when
  // the work cannot be recorded (the step has not run), and the work's own errors as they come.
  StepOutputs run(const StepData& data, const std::function<StepOutputs(const StepInputs&)>& work);
  // Reads the counts of every replayed step not read yet (waits for them), so that stats() counts every overflow.
  void settle();
  const StepGraphStats& stats() const { return stats_; }

 private:
  struct Kind {
    std::unique_ptr<StepInputs> inputs;
    std::unique_ptr<DeviceGraph> graph;
    StepOutputs outputs;                // the graph's, rewritten by each replay
    std::vector<at::Tensor> gradients;  // the graph's, per parameter (undefined: the kind does not reach it)
  };
  // A replayed step whose counts the host has not read: their page-locked copy, filled in stream order. Every
  // pending step ran under the current budget (the budget grows only once the pending checks are cleared).
  struct PendingCheck {
    at::Tensor counts;
    std::unique_ptr<DeviceEvent> copied;
  };
  StepOutputs run_budgeted(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work);
  // Queues the check of the step just replayed; returns its skip flag.
  at::Tensor queue_check();
  // Reads the oldest pending check (waiting for that step only); beyond its budget: grow it, drop the graphs.
  void check_oldest();
  void capture(Kind& kind, const std::function<StepOutputs(const StepInputs&)>& work);
  void drop_graphs();

  model::Avatar avatar_;
  at::Device device_;
  std::map<std::string, Kind> kinds_;
  GrowingBudget budget_;
  std::deque<PendingCheck> pending_;
  StepGraphStats stats_;
};

}  // namespace sfgs::train
