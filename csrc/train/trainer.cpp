#include "train/trainer.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <variant>
#include <vector>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "common/folder_lock.h"
#include "train/pose_refinement.h"
#include "train/results.h"
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

// `before`: the iterations of the run's earlier rounds, which options.stop_at counts too.
RunPlan plan_run(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                 const TrainOptions& options, int64_t before) {
  const int64_t iterations = config.schedule.iterations;
  RunPlan plan;
  plan.end = options.stop_at > 0 ? std::min(options.stop_at, iterations) : iterations;
  if (!fs::exists(run.checkpoint_file())) {
    if (options.resume)
      std::fprintf(stderr, "sfgs train: no checkpoint in '%s' to resume: starting a new run\n", run.path.c_str());
    return plan;
  }
  if (!options.resume) return plan;  // a forced new run (train_avatar refuses one that is not)
  plan.checkpoint.emplace(run.checkpoint_file());
  const CheckpointInfo& info = plan.checkpoint->info();
  refuse_unsafe_changes(info.config, config, run);
  refuse_rounds_iterations_change(info.config, config, run);
  refuse_other_data(info, dataset);
  plan.start = info.iteration;
  TORCH_CHECK(plan.start <= iterations, "cannot resume run '", run.path, "': it is at iteration ", plan.start,
              ", past the ", iterations, " iterations asked for (--iterations or schedule.iterations); ask for more ",
              "than ", plan.start, " to train further");
  TORCH_CHECK(options.stop_at == 0 || options.stop_at > plan.start, "cannot resume run '", run.path,
              "' to pause at --stop-at ", before + options.stop_at, ": it is already at iteration ",
              before + plan.start, before > 0 ? " (counting its earlier rounds)" : "");
  return plan;
}

// A run's start fits: the dataset with them applied, and the file's bytes, read once (the run keeps this copy).
struct StartFits {
  data::Dataset dataset;
  std::vector<unsigned char> bytes;
  std::string file;  // where they were read: the file asked for, or the run's own copy
};

// The run's start fits, where it has some: those asked for, or the copy a resumed run keeps (a resume may name the
// same fits again, not others); none otherwise.
std::optional<StartFits> read_start_fits(const data::Dataset& dataset, const RunFolder& run,
                                         const TrainOptions& options) {
  std::string file = options.start_fits;
  std::vector<unsigned char> bytes;
  if (options.resume && fs::exists(run.start_fits_file())) {
    bytes = file_bytes(run.start_fits_file());
    TORCH_CHECK(file.empty() || file_bytes(file) == bytes, "cannot resume run '", run.path, "' from start fits '", file,
                "': it started from other fits (", run.start_fits_file(), "); resume without --start-fits, or start ",
                "a new run (--force or another --out)");
    file = run.start_fits_file();
  } else if (!file.empty()) {
    TORCH_CHECK(!options.resume || !fs::exists(run.checkpoint_file()), "cannot resume run '", run.path,
                "' from start fits '", file, "': it started from the dataset's own fits; start a new run (--force or ",
                "another --out) to start from other fits");
    TORCH_CHECK(fs::is_regular_file(file), "--start-fits '", file,
                "' is neither a trained run's folder nor a refined-fits file (refined_fits.json)");
    bytes = file_bytes(file);
  } else {
    return std::nullopt;
  }
  nlohmann::json fits;
  try {
    fits = nlohmann::json::parse(bytes.begin(), bytes.end());
  } catch (const nlohmann::json::exception& e) {
    TORCH_CHECK(false, "start fits '", file, "' are not valid JSON: ", e.what());
  }
  StartFits start{dataset, std::move(bytes), file};
  const std::vector<int64_t> replaced = apply_refined_fits(start.dataset, fits, file);
  const std::vector<int64_t>& train_frames = dataset.split(data::Split::kTrain);
  for (const int64_t f : replaced)
    TORCH_CHECK(std::find(train_frames.begin(), train_frames.end(), f) != train_frames.end(), "start fits '", file,
                "' give frame '", dataset.frames[size_t(f)].name,
                "' a fit, but it is not a training frame of dataset '", dataset.source,
                "': give the refined fits of a run trained on this dataset and its split");
  TORCH_CHECK(!replaced.empty(), "start fits '", file, "' name none of the training frames of dataset '",
              dataset.source, "': give the refined fits of a run trained on this dataset");
  if (replaced.size() != fits.at("frames").size()) {
    std::set<std::string> names;
    for (const data::FrameRecord& r : dataset.frames) names.insert(r.name);
    for (const auto& [name, fit] : fits.at("frames").items())
      TORCH_CHECK(names.count(name) > 0, "start fits '", file, "' give frame '", name, "' a fit, but dataset '",
                  dataset.source, "' holds no such frame: give the refined fits of a run trained on this dataset");
  }
  return start;
}

// Keeps the log's entries up to the checkpoint's iteration: the steps a killed run made after its last checkpoint
// are run again, and must not appear twice.
void rewind_log(const RunFolder& run, int64_t iteration) {
  const int64_t dropped = truncate_log_after(run.log_file(), iteration);
  JsonLinesLog(run.log_file()).write({{"event", "resume"}, {"iteration", iteration}, {"dropped_entries", dropped}});
}

}  // namespace

void refuse_unsafe_changes(const TrainConfig& trained, const TrainConfig& requested, const RunFolder& run) {
  std::string refused;
  for (const ConfigChange& c : config_changes(trained, requested))
    if (!change_allowed_on_resume(c.key))
      refused += (refused.empty() ? "" : ", ") + c.key + " (" + c.before + " -> " + c.after + ")";
  TORCH_CHECK(refused.empty(), "cannot resume run '", run.path, "': the config asked for differs from the one it was ",
              "trained with in keys that change the model, its objective or its data: ", refused, ". On resume only ",
              "schedule.* and run.log_every, run.validate_every, run.checkpoint_every, run.validation_frames and ",
              "run.device may change; resume with the run's own config (no --config, config.yaml unchanged), or ",
              "start a new run (--force or another --out)");
}

void refuse_rounds_iterations_change(const TrainConfig& trained, const TrainConfig& requested, const RunFolder& run) {
  TORCH_CHECK(requested.pose_refinement.rounds == 1 || trained.schedule.iterations == requested.schedule.iterations,
              "cannot resume run '", run.path, "' with ", requested.schedule.iterations,
              " iterations a round: its rounds have ", trained.schedule.iterations,
              ", and a run of several rounds keeps them (--stop-at counts them); start a new run to change them");
}

std::vector<unsigned char> file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  TORCH_CHECK(in.good(), "cannot read '", path, "'");
  return std::vector<unsigned char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

double learning_rate_factor(const Schedule& schedule, int64_t iteration) {
  double factor = 1.0;
  if (schedule.warmup_iterations > 0 && iteration < schedule.warmup_iterations)
    factor = double(iteration + 1) / double(schedule.warmup_iterations);
  for (size_t i = 0; i < schedule.decay_at.size(); ++i)
    if (double(iteration) >= schedule.decay_at[i] * double(schedule.iterations)) factor = schedule.decay_factor[i];
  return factor;
}

TrainSummary train_round(const data::Dataset& given, const TrainConfig& config, const RunFolder& run,
                         const TrainOptions& options, int64_t before) {
  for (const std::string& name : remove_stale_temporaries(run.path))
    std::fprintf(stderr, "sfgs train: removed '%s', left in '%s' by a process that was killed\n", name.c_str(),
                 run.path.c_str());
  const std::optional<StartFits> start = read_start_fits(given, run, options);
  const data::Dataset& dataset = start ? start->dataset : given;
  if (start && options.progress)
    std::fprintf(stderr, "sfgs train: the training frames of '%s' start from the fits of '%s'\n", run.path.c_str(),
                 start->file.c_str());
  RunPlan plan = plan_run(dataset, config, run, options, before);
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
  session.add_part(make_start_fits_copy(start ? std::optional(start->bytes) : std::nullopt));
  if (plan.checkpoint)
    rewind_log(run, plan.start);
  else
    std::remove(run.log_file().c_str());
  session.open_log();
  return session.run(plan.start, plan.end);
}

void check_start_fits(const data::Dataset& dataset, const RunFolder& run, const TrainOptions& options) {
  read_start_fits(dataset, run, options);
}

}  // namespace sfgs::train
