#pragma once
// The state of one training call (internal to the trainer): the avatar and its optimiser, the losses, the frame
// sampler, the log and the watch for divergence, and the step, validation and checkpoint that act on them. What else a
// run does around its steps (pose refinement, the training records, the start-fits copy) plugs in as TrainingParts
// (train/training_parts.h).
#include <memory>
#include <optional>
#include <random>
#include <vector>

#include <torch/optim/adam.h>

#include "common/matmul_precision.h"
#include "train/adam_step.h"
#include "train/checkpoint.h"
#include "train/frame_cache.h"
#include "train/loss_watch.h"
#include "train/progress.h"
#include "train/step_graphs.h"
#include "train/training_parts.h"
#include "train/training_step.h"
#include "train/trainer.h"

namespace sfgs::train {

class TrainingSession {
 public:
  TrainingSession(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                  const TrainOptions& options);
  ~TrainingSession();
  // Continues from a checkpoint (verified as it loads): avatar, optimiser, sampler and time.
  void restore(CheckpointReader& checkpoint);
  // Runs iterations [start, end) and writes the log entries, validations and checkpoints they call for. The log
  // must be open (open_log) first.
  TrainSummary run(int64_t start, int64_t end);
  void open_log();
  // Plugs in a part after those the config asks for (make_training_parts); before restore() and run().
  void add_part(std::unique_ptr<TrainingPart> part);

 private:
  void step(int64_t iteration);
  // After the first step of a call: a CPU run whose remaining iterations are estimated longer than kLongCpuRunSeconds
  // is logged and, with progress on, told how long and how to shorten it.
  void warn_if_long(double first_step_seconds, int64_t remaining);
  void finish_step(int64_t done, int64_t end);
  double split_psnr(data::Split split);
  void validate(int64_t done);
  void checkpoint(int64_t done);
  [[noreturn]] void stop_diverged(const DivergenceError& e);

  const data::Dataset& dataset_;
  const TrainConfig& config_;
  const RunFolder& run_;
  const TrainOptions& options_;
  at::Device device_;
  Tf32MatmulScope tf32_;
  at::Tensor last_lpips_;           // the last step's LPIPS that measured it (loss.lpips_every), detached
  data::ReplayClock replay_clock_;  // each training frame's time, asked every step
  model::Avatar avatar_{nullptr};
  std::unique_ptr<torch::optim::Adam> optimizer_;
  std::unique_ptr<AdamStepper> adam_;  // steps optimizer_ (one fused kernel per group on CUDA)
  std::vector<double> base_rates_;
  std::unique_ptr<ImageLoss> image_loss_;
  std::unique_ptr<Regularisers> regularisers_;
  std::unique_ptr<FrameCache> frames_;
  std::unique_ptr<TrainingStep> step_;
  std::unique_ptr<StepGraphs> graphs_;  // null: steps run eagerly (CPU, stage timing, schedule.cuda_graphs off)
  std::vector<std::unique_ptr<TrainingPart>> parts_;
  std::unique_ptr<JsonLinesLog> log_;
  std::unique_ptr<ProgressBar> bar_;
  LossWatch watch_;
  std::mt19937_64 rng_;
  double training_seconds_ = 0;
  int64_t last_checkpoint_ = -1;  // iteration of the newest good checkpoint, -1 for none
  TrainSummary summary_;
};

}  // namespace sfgs::train
