// A run's rounds (rounds.h): each round is a run of train/trainer.h; here they are chained, resumed and cleared.
#include "train/rounds.h"

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <variant>
#include <vector>

#include <ATen/ATen.h>

#include "common/atomic_file.h"
#include "common/folder_lock.h"
#include "train/checkpoint.h"
#include "train/results.h"

namespace sfgs::train {
namespace fs = std::filesystem;

namespace {

bool finished_at(const RunFolder& run, int64_t iterations) {
  return fs::exists(run.checkpoint_file()) && CheckpointReader(run.checkpoint_file()).info().iteration >= iterations;
}

TrainSummary in_round(TrainSummary summary, int64_t round, int64_t rounds, const RunFolder& folder) {
  summary.round = round;
  summary.rounds = rounds;
  summary.folder = folder.path;
  return summary;
}

// options.stop_at, which counts the iterations of the whole run, as an iteration of round `round` (0: none).
int64_t round_stop(const TrainOptions& options, const TrainConfig& config, const RunFolder& run, int64_t round) {
  if (options.stop_at == 0) return 0;
  const int64_t before = (round - 1) * config.schedule.iterations;
  TORCH_CHECK(options.stop_at > before, "cannot resume run '", run.path, "' to pause at --stop-at ", options.stop_at,
              ": its first ", round - 1, " round(s) are done, iterations 1-", before, " of the run's ",
              config.pose_refinement.rounds * config.schedule.iterations, " (", config.pose_refinement.rounds,
              " rounds of ", config.schedule.iterations, ")");
  return options.stop_at - before;
}

// The rounds before the last (train_avatar): trains or continues those not finished. Returns the start fits of the
// last round, or the summary of a round the run paused in or at the end of.
std::variant<std::string, TrainSummary> train_earlier_rounds(const data::Dataset& dataset, const TrainConfig& config,
                                                             const RunFolder& run, const TrainOptions& options) {
  const int64_t rounds = config.pose_refinement.rounds, iterations = config.schedule.iterations;
  TrainConfig one_round = config;
  one_round.pose_refinement.rounds = 1;
  TrainOptions round_options = options;
  for (int64_t r = 1; r < rounds; ++r) {
    const RunFolder folder{run.round_folder(r)};
    if (!options.resume || !finished_at(folder, iterations)) {
      round_options.resume = options.resume && fs::exists(folder.checkpoint_file());
      round_options.stop_at = round_stop(options, config, run, r);
      if (options.progress)
        std::fprintf(stderr, "sfgs train: round %lld of %lld, in '%s'\n", (long long)r, (long long)rounds,
                     folder.path.c_str());
      const FolderLock lock(folder.path, "train");
      TrainSummary summary = train_round(dataset, one_round, folder, round_options, (r - 1) * iterations);
      if (!summary.finished || (options.stop_at > 0 && options.stop_at <= r * iterations)) {
        summary.finished = false;  // the run is not
        return in_round(std::move(summary), r, rounds, folder);
      }
    }
    round_options.start_fits = folder.refined_fits_file();
  }
  return round_options.start_fits;
}

// The round folders of `run` numbered `from` and up, claimed: each one's train and eval locks are held until they go,
// so that no process trains or evaluates a folder that is being removed, and one that another process holds is
// refused before anything goes.
struct ClaimedRounds {
  std::vector<fs::path> folders;
  std::vector<std::unique_ptr<FolderLock>> locks;

  void remove() const {
    for (const fs::path& folder : folders)
      TORCH_CHECK(remove_tree(folder.string()), "could not remove the round folder '", folder.string(), "'");
  }
};

ClaimedRounds claim_rounds_from(const RunFolder& run, int64_t from) {
  ClaimedRounds claimed;
  if (!fs::is_directory(run.path)) return claimed;
  for (const fs::directory_entry& entry : fs::directory_iterator(run.path)) {
    const std::string name = entry.path().filename().string();
    if (!entry.is_directory() || name.rfind("round-", 0) != 0) continue;
    const std::string number = name.substr(6);
    const bool numbered = !number.empty() && number.size() < 10 &&
                          std::all_of(number.begin(), number.end(), [](unsigned char c) { return std::isdigit(c); });
    if (numbered && std::stoll(number) >= from) claimed.folders.push_back(entry.path());
  }
  for (const fs::path& folder : claimed.folders)
    for (const char* purpose : {"train", "eval"})
      claimed.locks.push_back(std::make_unique<FolderLock>(folder.string(), purpose));
  return claimed;
}

// A resume of a run of several rounds (or of one round where such a run paused) checked against what the run stored:
// before its last round, the config.yaml written before its round 1 (the same model, objective and data keys, rounds
// among them, and iterations a round; from its last round on, plan_run checks them against the checkpoint), and for
// several rounds the start fits its round 1 began from.
void check_resumed_rounds(const TrainConfig& config, const RunFolder& run, const TrainOptions& options) {
  if (!fs::exists(run.checkpoint_file()) && fs::exists(run.config_file())) {
    const TrainConfig stored = TrainConfig::from_stored_yaml_file(run.config_file());
    refuse_unsafe_changes(stored, config, run);
    refuse_rounds_iterations_change(stored, config, run);
  }
  if (config.pose_refinement.rounds == 1 || options.start_fits.empty()) return;
  const RunFolder first_round{run.round_folder(1)};
  TORCH_CHECK(fs::exists(first_round.start_fits_file()) &&
                  file_bytes(first_round.start_fits_file()) == file_bytes(options.start_fits),
              "cannot resume run '", run.path, "' from start fits '", options.start_fits,
              "': its round 1 started from other fits; resume without --start-fits, or start a new run (--force or ",
              "another --out)");
}

}  // namespace

std::string resumable_checkpoint(const RunFolder& run) {
  if (fs::exists(run.checkpoint_file())) return run.checkpoint_file();
  const RunFolder first_round{run.round_folder(1)};
  if (fs::exists(run.config_file()) && fs::exists(first_round.checkpoint_file())) return first_round.checkpoint_file();
  return "";
}

std::string start_fits_file(const std::string& given) {
  if (!fs::is_directory(given)) return given;
  const RunFolder earlier{given};
  TORCH_CHECK(fs::exists(earlier.checkpoint_file()), "--start-fits: '", earlier.path,
              "' is a folder without a checkpoint.pt, not a trained run; give a run folder or a refined-fits file");
  TORCH_CHECK(fs::exists(earlier.refined_fits_file()) &&
                  CheckpointReader(earlier.checkpoint_file()).info().pose_refinement.defined(),
              "--start-fits: run '", earlier.path, "' did not refine its poses (no refined fits beside its ",
              "checkpoint); give a run trained with pose_refinement.enabled, or a refined-fits file");
  return earlier.refined_fits_file();
}

TrainSummary train_avatar(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                          const TrainOptions& options) {
  config.validate();
  TORCH_CHECK(!dataset.split(data::Split::kTrain).empty(), "dataset '", dataset.source, "' has no training frames");
  TORCH_CHECK(config.device != "cuda" || cuda_backend_available(),
              "run.device is cuda but this build of sfgs has no CUDA backend");
  const FolderLock lock(run.path, "train");
  const int64_t rounds = config.pose_refinement.rounds;
  const RunFolder first_round{run.round_folder(1)};
  TORCH_CHECK(options.resume || options.overwrite ||
                  !(fs::exists(run.checkpoint_file()) || fs::exists(first_round.checkpoint_file())),
              "run folder '", run.path, "' already holds a checkpoint",
              fs::exists(run.checkpoint_file()) ? "" : " (of its round 1)",
              ": pass --resume to continue it or --force to start afresh");
  // A new run replaces what commands derived from the older one's checkpoint (its evaluations).
  if (!options.resume) remove_derived_outputs(run);
  // A resume of several rounds, or of one round where a run of several paused before its last.
  if (options.resume && (rounds > 1 || (fs::is_directory(first_round.path) && !fs::exists(run.checkpoint_file()))))
    check_resumed_rounds(config, run, options);
  TrainOptions last_round = options;
  if (rounds > 1 && options.resume && fs::exists(run.checkpoint_file())) {
    last_round.start_fits.clear();  // round 1's, checked above; the last round resumes from its own copy
  } else if (rounds > 1) {
    if (!options.resume) {
      // A new run: its start fits are checked before the folder's older run goes. Its config is written now, so that
      // a resume finds a run paused before its last round.
      TrainOptions first_round_start;
      first_round_start.start_fits = options.start_fits;
      check_start_fits(dataset, first_round, first_round_start);
      claim_rounds_from(run, 1).remove();
      for (const std::string& file : {run.checkpoint_file(), run.refined_fits_file(), run.start_fits_file()})
        fs::remove(file);
      const std::string config_text = config.to_yaml();
      write_file_atomically(run.config_file(), std::vector<unsigned char>(config_text.begin(), config_text.end()),
                            true);
    }
    std::variant<std::string, TrainSummary> earlier = train_earlier_rounds(dataset, config, run, options);
    if (std::holds_alternative<TrainSummary>(earlier)) return std::get<TrainSummary>(std::move(earlier));
    last_round.start_fits = std::get<std::string>(earlier);
    last_round.resume = false;  // a new round, not a resume without a checkpoint
    if (options.progress)
      std::fprintf(stderr, "sfgs train: round %lld of %lld, in '%s'\n", (long long)rounds, (long long)rounds,
                   run.path.c_str());
  }
  last_round.stop_at = round_stop(options, config, run, rounds);
  // A new run of one round claims an older run's round folders now, and removes them once it has trained.
  const ClaimedRounds older_rounds = !options.resume && rounds == 1 ? claim_rounds_from(run, 1) : ClaimedRounds();
  TrainSummary summary = train_round(dataset, config, run, last_round, (rounds - 1) * config.schedule.iterations);
  older_rounds.remove();
  // Evaluations of the checkpoint this call replaced no longer describe the run.
  remove_stale_results(run);
  return in_round(std::move(summary), rounds, rounds, run);
}

}  // namespace sfgs::train
