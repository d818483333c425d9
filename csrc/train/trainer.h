#pragma once
// The C++ trainer: Adam with per-group learning rates, linear warm-up and step decay, random background colours,
// periodic validation, atomic checkpoints that resume to an identical continuation, a progress bar and JSON-lines logs.
// A run folder belongs to one training process at a time (FolderLock); a resumed run keeps the model and data it was
// trained with (only schedule and logging may change), and a diverging run stops at the first non-finite loss with
// its last good checkpoint intact.
#include <string>
#include <vector>

#include "data/dataset.h"
#include "train/run_folder.h"

namespace sfgs::train {

struct TrainOptions {
  bool resume = false;     // continue from the run folder's checkpoint
  bool overwrite = false;  // start afresh even if the folder holds a run
  bool progress = true;    // progress bar on stderr
  // Pause after this many iterations (checkpoint written) so that a later --resume continues the same run;
  // 0 runs to the end of the schedule. A run of several rounds counts them all (train_avatar).
  int64_t stop_at = 0;
  // A refined-fits file (an earlier run's refined_fits.json) whose fits the training frames start from instead of the
  // dataset's: a second round on fits an earlier run refined. It may name training frames only. The run keeps a copy
  // (RunFolder::start_fits_file) that a resume applies again (it may name the same fits, not others) and every command
  // reading the run applies; a new run without start fits removes an old copy.
  std::string start_fits;
};

struct TrainSummary {
  int64_t first_iteration = 0;  // the iteration this call started from (0, or the checkpoint's when resuming)
  int64_t iterations = 0;       // the iteration the run stopped at
  int64_t steps = 0;            // steps this call ran (0: the run had already reached its end)
  bool finished = false;        // the run has done every iteration of its schedule
  double seconds = 0;           // wall time of this call
  double training_seconds = 0;  // time spent in training steps over the whole run (resumes included)
  double step_seconds = 0;      // time spent in this call's training steps
  double final_loss = 0;        // the last logged total loss of this call (when steps > 0)
  double validation_psnr = 0;   // last validation of this call (white background, evaluation mask); NaN if none
  bool has_validation_frames = false;
  int64_t round = 1, rounds = 1;  // the round this call ended in, of the run's pose_refinement.rounds
  std::string folder;             // that round's run folder (RunFolder::round_folder; the run's own for the last)
};

// Learning-rate factor at `iteration` (0-based): linear warm-up, then the step decays.
double learning_rate_factor(const Schedule& schedule, int64_t iteration);

// One validation of a run: its masked PSNRs (NaN where the split is empty) after `iteration` steps that took
// `training_seconds` (validation and checkpoints excluded).
struct ErrorCurvePoint {
  int64_t iteration = 0;
  double training_seconds = 0, val_psnr = 0, test_psnr = 0;
};

// Every validation of a run, read back from its log.jsonl (a resumed run's repeated iterations: the last wins),
// also written atomically as CSV to `csv_path`: the run-time-versus-error curve.
std::vector<ErrorCurvePoint> write_error_curve_csv(const RunFolder& run, const std::string& csv_path);

// Trains (or, with options.resume and a checkpoint in `run`, continues) the avatar `config` describes on `dataset`.
// Everything is validated before any file of the run is touched: a resume with a config that changes the model or
// its objective (anything but schedule and logging keys), on another dataset, or to an iteration the run has
// passed, is refused with the reason, and the run's files stay as they were.
// With pose_refinement.rounds N > 1 the rounds train one after the other: round K < N in run.round_folder(K) (a run
// folder of its own, config rounds 1; round 1 starts from options.start_fits), each later one from the refined fits
// of the one before, round N in `run`. The run's config.yaml (rounds N) is written before round 1, so that a resume
// finds a run paused in an earlier round; a resume continues the round in progress, and options.stop_at counts the
// iterations of the whole run (rounds x schedule.iterations: 2,000 with rounds of 1,500 pauses round 2 at 500), and
// a resume keeps the rounds, the iterations a round and round 1's start fits. A new run that is not forced is refused
// where the run or its round 1 holds a checkpoint; a forced one of several rounds clears the old run's checkpoint
// before its round 1 (once its start fits are checked), and every new run removes the older run's round folders
// (refused, before it trains, while another process trains or evaluates one of them).
TrainSummary train_avatar(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                          const TrainOptions& options);

}  // namespace sfgs::train
