#pragma once
// The C++ trainer, one round of a run (train/rounds.h runs a run's rounds): Adam with per-group learning rates, linear
// warm-up and step decay, random background colours, periodic validation, atomic checkpoints that resume to an
// identical continuation, a progress bar and JSON-lines logs.
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

// One round of a run (train/rounds.h's train_avatar runs the rounds): trains, or with options.resume and a checkpoint
// in `run` continues, the avatar `config` describes on `dataset`, in `run`, whose train lock the caller holds, after
// `before` iterations of the run's earlier rounds (which options.stop_at counts too). Everything is validated before
// any file of the round is touched: a resume with a config that changes the model or its objective, on another
// dataset, or to an iteration the round has passed, is refused with the reason, and its files stay as they were.
TrainSummary train_round(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                         const TrainOptions& options, int64_t before);

// What a resume may not change, refused with the keys and the way out: `requested` against what `run` was trained
// with (`trained`) in anything but the schedule and logging keys; and for a run of several rounds, the iterations a
// round.
void refuse_unsafe_changes(const TrainConfig& trained, const TrainConfig& requested, const RunFolder& run);
void refuse_rounds_iterations_change(const TrainConfig& trained, const TrainConfig& requested, const RunFolder& run);

// Checks the start fits a round of `run` would begin from (options.start_fits, or the copy a resumed round keeps)
// against `dataset`, as train_round does before it writes anything.
void check_start_fits(const data::Dataset& dataset, const RunFolder& run, const TrainOptions& options);

// The bytes of a file (refused by name when it cannot be read).
std::vector<unsigned char> file_bytes(const std::string& path);

}  // namespace sfgs::train
