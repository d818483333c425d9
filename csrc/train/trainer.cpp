#include "train/trainer.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <vector>

#include <ATen/ATen.h>

#include "common/atomic_file.h"
#include "common/folder_lock.h"
#include "train/pose_refinement.h"
#include "train/training_session.h"

namespace sfgs::train {
namespace fs = std::filesystem;

namespace {

// Where this call starts and stops, and the checkpoint it continues (when resuming): everything decided and checked
// before any file of the run is written.
struct RunPlan {
  std::optional<CheckpointReader> checkpoint;
  int64_t start = 0, end = 0;
};

void refuse_unsafe_changes(const TrainConfig& trained, const TrainConfig& requested, const RunFolder& run) {
  std::string refused;
  for (const ConfigChange& c : config_changes(trained, requested))
    if (!change_allowed_on_resume(c.key)) refused += (refused.empty() ? "" : ", ") + c.key + " (" + c.before + " -> " + c.after + ")";
  TORCH_CHECK(refused.empty(), "cannot resume run '", run.path, "': the config asked for differs from the one it was ",
              "trained with in keys that change the model, its objective or its data: ", refused, ". On resume only ",
              "schedule.* and run.log_every, run.validate_every, run.checkpoint_every, run.validation_frames and ",
              "run.device may change; resume with the run's own config (no --config, config.yaml unchanged), or ",
              "start a new run (--force or another --out)");
}

void refuse_other_data(const CheckpointInfo& info, const data::Dataset& dataset) {
  if (!info.dataset_fingerprint.empty()) {
    TORCH_CHECK(info.dataset_fingerprint == dataset.fingerprint(), "cannot resume: dataset '", dataset.source,
                "' is not the one this run was trained on ('", info.dataset, "'; fingerprints ",
                info.dataset_fingerprint, " and ", dataset.fingerprint(), " differ): resuming would mix two videos. ",
                "Pass --data with the run's dataset, or start a new run");
    return;
  }
  // Version 1 checkpoints hold only the path.
  std::error_code ec;
  const fs::path a = fs::weakly_canonical(info.dataset, ec), b = fs::weakly_canonical(dataset.source, ec);
  TORCH_CHECK(ec || a == b, "cannot resume: dataset '", dataset.source, "' is not the one this run was trained on ('",
              info.dataset, "')");
}

RunPlan plan_run(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                 const TrainOptions& options) {
  const int64_t iterations = config.schedule.iterations;
  RunPlan plan;
  plan.end = options.stop_at > 0 ? std::min(options.stop_at, iterations) : iterations;
  if (!fs::exists(run.checkpoint_file())) {
    if (options.resume)
      std::fprintf(stderr, "sfgs train: no checkpoint in '%s' to resume: starting a new run\n", run.path.c_str());
    return plan;
  }
  TORCH_CHECK(options.resume || options.overwrite, "run folder '", run.path,
              "' already holds a checkpoint: pass --resume to continue it or --force to start afresh");
  if (!options.resume) return plan;
  plan.checkpoint.emplace(run.checkpoint_file());
  const CheckpointInfo& info = plan.checkpoint->info();
  refuse_unsafe_changes(info.config, config, run);
  refuse_other_data(info, dataset);
  plan.start = info.iteration;
  TORCH_CHECK(plan.start <= iterations, "cannot resume run '", run.path, "': it is at iteration ", plan.start,
              ", past the ", iterations, " iterations asked for (--iterations or schedule.iterations); ask for more ",
              "than ", plan.start, " to train further");
  TORCH_CHECK(options.stop_at == 0 || options.stop_at > plan.start, "cannot resume run '", run.path,
              "' to pause at --stop-at ", options.stop_at, ": it is already at iteration ", plan.start);
  return plan;
}

// The dataset with the training frames' start fits applied, where the run has some: those asked for (a new run) or
// those a resumed run started from; none otherwise.
std::optional<data::Dataset> with_start_fits(const data::Dataset& dataset, const RunFolder& run,
                                             const TrainOptions& options) {
  const bool resuming = options.resume && fs::exists(run.checkpoint_file());
  TORCH_CHECK(options.start_fits.empty() || !resuming, "cannot resume run '", run.path, "' from start fits '",
              options.start_fits, "': a resumed run keeps the fits it started from (", run.start_fits_file(),
              " when it had any); start a new run (--force or another --out) to start from other fits");
  const std::string file = !options.start_fits.empty()
                               ? options.start_fits
                               : (resuming && fs::exists(run.start_fits_file()) ? run.start_fits_file() : "");
  if (file.empty()) return std::nullopt;
  data::Dataset started = dataset;
  const std::vector<int64_t> replaced = apply_refined_fits(started, file);
  const std::vector<int64_t>& train_frames = dataset.split(data::Split::kTrain);
  const bool any = std::any_of(replaced.begin(), replaced.end(), [&](int64_t f) {
    return std::find(train_frames.begin(), train_frames.end(), f) != train_frames.end();
  });
  TORCH_CHECK(any, "start fits '", file, "' name none of the training frames of dataset '", dataset.source,
              "': give the refined fits of a run trained on this dataset");
  return started;
}

std::vector<unsigned char> file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  TORCH_CHECK(in.good(), "cannot read '", path, "'");
  return std::vector<unsigned char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// Keeps the log's entries up to the checkpoint's iteration: the steps a killed run made after its last checkpoint
// are run again, and must not appear twice.
void rewind_log(const RunFolder& run, int64_t iteration) {
  const int64_t dropped = truncate_log_after(run.log_file(), iteration);
  JsonLinesLog(run.log_file()).write({{"event", "resume"}, {"iteration", iteration}, {"dropped_entries", dropped}});
}

}  // namespace

double learning_rate_factor(const Schedule& schedule, int64_t iteration) {
  double factor = 1.0;
  if (schedule.warmup_iterations > 0 && iteration < schedule.warmup_iterations)
    factor = double(iteration + 1) / double(schedule.warmup_iterations);
  for (size_t i = 0; i < schedule.decay_at.size(); ++i)
    if (double(iteration) >= schedule.decay_at[i] * double(schedule.iterations)) factor = schedule.decay_factor[i];
  return factor;
}

TrainSummary train_avatar(const data::Dataset& given, const TrainConfig& config, const RunFolder& run,
                          const TrainOptions& options) {
  config.validate();
  TORCH_CHECK(!given.split(data::Split::kTrain).empty(), "dataset '", given.source, "' has no training frames");
  TORCH_CHECK(config.device != "cuda" || cuda_backend_available(),
              "run.device is cuda but this build of sfgs has no CUDA backend");
  const FolderLock lock(run.path, "train");
  for (const std::string& name : remove_stale_temporaries(run.path))
    std::fprintf(stderr, "sfgs train: removed '%s', left in '%s' by a process that was killed\n", name.c_str(),
                 run.path.c_str());
  const std::optional<data::Dataset> started = with_start_fits(given, run, options);
  const data::Dataset& dataset = started ? *started : given;
  RunPlan plan = plan_run(dataset, config, run, options);
  TrainingSession session(dataset, config, run, options);
  if (plan.checkpoint) session.restore(*plan.checkpoint);
  if (plan.checkpoint && plan.start == plan.end) {
    TrainSummary done;
    done.first_iteration = done.iterations = plan.start;
    done.finished = plan.start == config.schedule.iterations;
    done.training_seconds = plan.checkpoint->info().training_seconds;
    done.validation_psnr = std::nan("");
    return done;
  }
  // Everything is validated: only now are the run's files written.
  const std::string config_text = config.to_yaml();
  write_file_atomically(run.config_file(), std::vector<unsigned char>(config_text.begin(), config_text.end()), true);
  if (!options.start_fits.empty())
    write_file_atomically(run.start_fits_file(), file_bytes(options.start_fits), true);
  else if (!plan.checkpoint)
    std::remove(run.start_fits_file().c_str());  // a new run's training frames keep the dataset's fits
  if (plan.checkpoint)
    rewind_log(run, plan.start);
  else
    std::remove(run.log_file().c_str());
  session.open_log();
  return session.run(plan.start, plan.end);
}

}  // namespace sfgs::train
