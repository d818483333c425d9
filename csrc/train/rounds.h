#pragma once
// A training run's rounds, resume and start fits in one place: train_avatar runs a run's rounds (pose refinement's
// rounds, each a round of train/trainer.h), and the two questions a command asks of a run folder before it trains:
// which checkpoint a resume continues, and which refined fits a --start-fits argument names.
#include <string>

#include "data/dataset.h"
#include "train/run_folder.h"
#include "train/trainer.h"

namespace sfgs::train {

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

// The checkpoint a resume of `run` continues: its own, or, for a run of several rounds paused before its last (its
// config.yaml written, no checkpoint of its own), its round 1's; empty when it has none.
std::string resumable_checkpoint(const RunFolder& run);

// The refined-fits file `given` names: a trained run's folder stands for its refined fits (refused by name when it
// holds no checkpoint or did not refine its poses); a file is returned as it is (train_round checks it).
std::string start_fits_file(const std::string& given);

}  // namespace sfgs::train
