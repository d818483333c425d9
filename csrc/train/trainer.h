#pragma once
// The C++ trainer: Adam with per-group learning rates, linear warm-up and step decay, random background colours,
// periodic validation, atomic checkpoints that resume to an identical continuation, a progress bar and JSON-lines logs.
#include <functional>
#include <string>

#include "data/dataset.h"
#include "train/run_folder.h"

namespace sfgs::train {

struct TrainOptions {
  bool resume = false;     // continue from the run folder's checkpoint
  bool overwrite = false;  // start afresh even if the folder holds a run
  bool progress = true;    // progress bar on stderr
};

struct TrainSummary {
  int64_t iterations = 0;
  double seconds = 0;
  double final_loss = 0;
  double validation_psnr = 0;  // last validation (white background, evaluation mask); NaN without val frames
};

// Learning-rate factor at `iteration` (0-based): linear warm-up, then the step decays.
double learning_rate_factor(const Schedule& schedule, int64_t iteration);

TrainSummary train_avatar(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                          const TrainOptions& options);

}  // namespace sfgs::train
