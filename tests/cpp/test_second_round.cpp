// A second round (train/trainer.h TrainOptions::start_fits): a run whose training frames start from an earlier run's
// refined fits trains on them, keeps them through a pause and a resume (the resumed dataset's fingerprint would differ
// without them) and gives them, under its own refined fits, to every command reading it; a resume from other fits,
// fits that name no training frame or a frame that is not one are refused; a new run in the same folder without them
// trains on the dataset's own fits, and a start-fits copy left beside such a run does not change what it reads. A run
// of several rounds (pose_refinement.rounds) trains the same in one command; a new one leaves an older run's rounds
// alone while an eval reads one.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "common/folder_lock.h"
#include "test_body_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/checkpoint.h"
#include "train/pose_refinement.h"
#include "train/run_folder.h"
#include "train/rounds.h"
#include "train/trainer.h"

namespace sfgs::testing {
namespace {
namespace fs = std::filesystem;

bool is_training_frame(const data::Dataset& dataset, int64_t f) {
  const std::vector<int64_t>& train_frames = dataset.split(data::Split::kTrain);
  return std::find(train_frames.begin(), train_frames.end(), f) != train_frames.end();
}

// Expects every frame of `read` to have the body pose of `expected` for training frames, of `dataset` for the others.
void expect_training_fits(const data::Dataset& read, const data::Dataset& expected, const data::Dataset& dataset,
                          const std::string& what) {
  for (int64_t f = 0; f < dataset.size(); ++f) {
    const data::Dataset& source = is_training_frame(dataset, f) ? expected : dataset;
    EXPECT_TRUE(read.frames[size_t(f)].pose.body_pose.equal(source.frames[size_t(f)].pose.body_pose))
        << what << ": frame " << f;
  }
}

void write_json(const std::string& path, const nlohmann::json& j) { std::ofstream(path) << j.dump(); }

// The tiny config with pose refinement: one alignment pass, in the middle of the run.
train::TrainConfig tiny_refining_config() {
  train::TrainConfig c = tiny_train_config();
  c.pose_refinement.enabled = true;
  c.pose_refinement.align_at = {0.5};
  c.pose_refinement.align_iterations = 4;
  return c;
}

TEST(TrainPoseRefinement, ASecondRoundStartsFromAnEarlierRunsRefinedFits) {
  TempFolder folder;
  const data::Dataset dataset = tiny_video(folder, 10, 32);
  const train::TrainConfig refining = tiny_refining_config();
  const train::TrainConfig plain = tiny_train_config();
  const train::RunFolder first{folder / "first"}, second{folder / "second"}, third{folder / "third"};
  train::train_avatar(dataset, refining, first, quiet());
  const data::Dataset first_fits = train::read_run_dataset(train::load_trained_avatar(first, at::kCPU), "");
  int64_t moved = 0;
  for (int64_t f = 0; f < dataset.size(); ++f)
    moved += !first_fits.frames[size_t(f)].pose.body_pose.equal(dataset.frames[size_t(f)].pose.body_pose);
  ASSERT_GT(moved, 0) << "the first round's pass moved no fit";

  // Without refinement the second round's training fits are the start fits.
  train::TrainOptions start = quiet();
  start.start_fits = first.refined_fits_file();
  train::train_avatar(dataset, plain, second, start);
  expect_training_fits(train::read_run_dataset(train::load_trained_avatar(second, at::kCPU), ""), first_fits, dataset,
                       "plain second round");

  // A run folder stands for its refined fits; one that did not refine, or holds no run, is refused by name.
  EXPECT_EQ(train::start_fits_file(first.path), first.refined_fits_file());
  EXPECT_EQ(train::start_fits_file(first.refined_fits_file()), first.refined_fits_file());
  const std::string empty = folder / "empty";
  std::filesystem::create_directories(empty);
  expect_error([&] { train::start_fits_file(second.path); }, {"did not refine its poses"});
  expect_error([&] { train::start_fits_file(empty); }, {"without a checkpoint.pt"});
  EXPECT_EQ(train::resumable_checkpoint(first), first.checkpoint_file());
  EXPECT_EQ(train::resumable_checkpoint(train::RunFolder{empty}), "");

  // With refinement, paused and resumed (naming the same fits again): its own refined fits, over the start fits.
  start.stop_at = 3;
  train::train_avatar(dataset, refining, third, start);
  ASSERT_TRUE(fs::exists(third.start_fits_file()));
  train::TrainOptions resume = quiet();
  resume.resume = true;
  resume.start_fits = first.refined_fits_file();
  train::train_avatar(dataset, refining, third, resume);
  const train::TrainedAvatar trained = train::load_trained_avatar(third, at::kCPU);
  EXPECT_EQ(trained.iteration, refining.schedule.iterations);
  data::Dataset third_fits = dataset;
  train::apply_refined_fits(third_fits, third.refined_fits_file());
  expect_training_fits(train::read_run_dataset(trained, ""), third_fits, dataset, "refined second round");

  // Other fits on resume, fits that name no training frame, or a frame that is not one.
  nlohmann::json other = nlohmann::json::parse(std::ifstream(first.refined_fits_file()));
  const std::string first_name = other.at("frames").begin().key();
  other["frames"][first_name]["transl"][0] = 0.5;
  const std::string other_file = folder / "other_fits.json";
  write_json(other_file, other);
  resume.start_fits = other_file;
  expect_error([&] { train::train_avatar(dataset, refining, third, resume); }, {"cannot resume", "other fits"});
  train::TrainOptions fresh = quiet();
  fresh.overwrite = true;
  const std::string empty_file = folder / "empty_fits.json";
  write_json(empty_file, {{"format", "sfgs-refined-fits"}, {"version", 1}, {"frames", nlohmann::json::object()}});
  fresh.start_fits = empty_file;
  expect_error([&] { train::train_avatar(dataset, plain, second, fresh); },
               {"empty_fits.json", "none of the training"});
  const int64_t test_frame = dataset.split(data::Split::kTest).front();
  other["frames"][dataset.frames[size_t(test_frame)].name] = other.at("frames").at(first_name);
  write_json(other_file, other);
  fresh.start_fits = other_file;
  expect_error([&] { train::train_avatar(dataset, plain, second, fresh); },
               {dataset.frames[size_t(test_frame)].name, "not a training frame"});
  other["frames"].erase(dataset.frames[size_t(test_frame)].name);
  other["frames"]["no_such_frame"] = other.at("frames").at(first_name);
  write_json(other_file, other);
  expect_error([&] { train::train_avatar(dataset, plain, second, fresh); },
               {"give frame 'no_such_frame' a fit", "holds no such frame"});

  // A new run without start fits: the copy goes, and the dataset's own fits are read, even with a copy left beside.
  fresh.start_fits.clear();
  train::train_avatar(dataset, plain, second, fresh);
  EXPECT_FALSE(fs::exists(second.start_fits_file()));
  // A copy that does not belong to a run's checkpoint (the run's dataset as read has its fingerprint) changes nothing,
  // its refined fits included.
  fs::copy_file(other_file, second.start_fits_file());
  expect_training_fits(train::read_run_dataset(train::load_trained_avatar(second, at::kCPU), ""), dataset, dataset,
                       "a run on the dataset's own fits");
  fs::copy_file(third.start_fits_file(), first.start_fits_file());
  expect_training_fits(train::read_run_dataset(train::load_trained_avatar(first, at::kCPU), ""), first_fits, dataset,
                       "a first round with a copy beside it");
}

// pose_refinement.rounds: one run trains what the two commands of a second round train, the same however it is
// paused and resumed (in its first round or its last), and the run's config, folders and progress say which round it
// is in and which fits it starts from.
TEST(TrainPoseRefinement, RoundsTrainInOneRunWhatTwoRunsWould) {
  TempFolder folder;
  const data::Dataset dataset = tiny_video(folder, 10, 32);
  const train::TrainConfig refining = tiny_refining_config();
  train::TrainConfig two_rounds = refining;
  two_rounds.pose_refinement.rounds = 2;
  const train::RunFolder first{folder / "first"}, second{folder / "second"}, whole{folder / "whole"},
      paused{folder / "paused"};
  train::train_avatar(dataset, refining, first, quiet());
  train::TrainOptions start = quiet();
  start.start_fits = first.refined_fits_file();
  train::train_avatar(dataset, refining, second, start);

  const train::TrainSummary done = train::train_avatar(dataset, two_rounds, whole, quiet());
  EXPECT_TRUE(done.finished);
  EXPECT_EQ(done.round, 2);
  EXPECT_EQ(done.folder, whole.path);
  EXPECT_EQ(read_bytes(train::RunFolder{whole.round_folder(1)}.refined_fits_file()),
            read_bytes(first.refined_fits_file()));
  EXPECT_EQ(read_bytes(whole.start_fits_file()), read_bytes(first.refined_fits_file()));
  EXPECT_EQ(read_bytes(whole.refined_fits_file()), read_bytes(second.refined_fits_file()));
  EXPECT_EQ(train::TrainConfig::from_stored_yaml_file(whole.config_file()).pose_refinement.rounds, 2);

  // Paused in round 1, again in round 2 (at its iteration 3), then resumed to the end: the same fits.
  train::TrainOptions pause = quiet();
  pause.stop_at = 2;
  train::TrainSummary s = train::train_avatar(dataset, two_rounds, paused, pause);
  EXPECT_FALSE(s.finished);
  EXPECT_EQ(s.round, 1);
  EXPECT_EQ(s.folder, paused.round_folder(1));
  EXPECT_FALSE(fs::exists(paused.checkpoint_file()));
  EXPECT_EQ(train::TrainConfig::from_stored_yaml_file(paused.config_file()).pose_refinement.rounds, 2);
  expect_error([&] { train::train_avatar(dataset, two_rounds, paused, quiet()); },
               {"already holds a checkpoint", "round 1", "--resume"});
  pause.resume = true;
  pause.stop_at = two_rounds.schedule.iterations + 3;  // --stop-at counts both rounds' iterations
  pause.progress = true;                               // which fits each round starts from is said
  ::testing::internal::CaptureStderr();
  s = train::train_avatar(dataset, two_rounds, paused, pause);
  const std::string round_two = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(
      round_two.find("start from the fits of '" + train::RunFolder{paused.round_folder(1)}.refined_fits_file() + "'"),
      std::string::npos)
      << round_two;
  pause.progress = false;
  EXPECT_FALSE(s.finished);
  EXPECT_EQ(s.round, 2);
  EXPECT_EQ(s.iterations, 3);
  EXPECT_TRUE(fs::exists(paused.start_fits_file()));
  pause.stop_at = 5;
  expect_error([&] { train::train_avatar(dataset, two_rounds, paused, pause); },
               {"--stop-at 5", "first 1 round(s) are done"});
  train::TrainOptions resume = quiet();
  resume.resume = true;
  train::TrainConfig longer = two_rounds;  // in its last round too, the run keeps its iterations a round
  longer.schedule.iterations += 2;
  expect_error([&] { train::train_avatar(dataset, longer, paused, resume); }, {"iterations a round"});
  resume.progress = true;
  ::testing::internal::CaptureStderr();
  s = train::train_avatar(dataset, two_rounds, paused, resume);
  const std::string resumed = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(resumed.find("start from the fits of '" + paused.start_fits_file() + "'"), std::string::npos) << resumed;
  EXPECT_TRUE(s.finished);
  EXPECT_EQ(s.round, 2);
  EXPECT_EQ(read_bytes(train::RunFolder{paused.round_folder(1)}.refined_fits_file()),
            read_bytes(first.refined_fits_file()));
  EXPECT_EQ(read_bytes(paused.start_fits_file()), read_bytes(first.refined_fits_file()));
  EXPECT_EQ(read_bytes(paused.refined_fits_file()), read_bytes(second.refined_fits_file()));

  // A new one-round run in the folder, forced: refused before it trains while an eval reads the round folder, which
  // goes once the run has trained.
  train::TrainOptions fresh = quiet();
  fresh.overwrite = true;
  {
    const std::vector<unsigned char> fits = read_bytes(paused.refined_fits_file());
    const FolderLock evaluating(paused.round_folder(1), "eval");
    expect_error_mentioning([&] { train::train_avatar(dataset, refining, paused, fresh); },
                            "in use by another sfgs eval");
    EXPECT_EQ(read_bytes(paused.refined_fits_file()), fits);
  }
  train::train_avatar(dataset, refining, paused, fresh);
  EXPECT_FALSE(fs::exists(paused.round_folder(1)));
  EXPECT_FALSE(fs::exists(paused.start_fits_file()));

  // Rounds need refinement: a later round starts from the refined fits of the one before.
  train::TrainConfig plain = tiny_train_config();
  plain.pose_refinement.rounds = 2;
  expect_error([&] { plain.validate(); }, {"pose_refinement.rounds", "not enabled"});
  two_rounds.pose_refinement.rounds = 0;
  expect_error([&] { two_rounds.validate(); }, {"pose_refinement.rounds"});
}

// A resume continues the run of rounds it finds, no other: a config with other rounds, iterations or avatar, or other
// start fits, is refused with the run's files as they were, and a forced new run over a finished one trains its
// round 1 afresh rather than taking the old run's.
TEST(TrainPoseRefinement, RoundsResumeOnlyTheRunTheyBelongTo) {
  TempFolder folder;
  const data::Dataset dataset = tiny_video(folder, 10, 32);
  train::TrainConfig two_rounds = tiny_refining_config();
  two_rounds.pose_refinement.rounds = 2;
  const train::RunFolder run{folder / "run"}, reference{folder / "reference"};
  train::train_avatar(dataset, two_rounds, reference, quiet());
  train::train_avatar(dataset, two_rounds, run, quiet());

  // A forced new run over the finished one, paused in its round 1: the old rounds are gone (round-2/ stands for those
  // of an older run of more rounds).
  fs::copy(run.round_folder(1), run.round_folder(2), fs::copy_options::recursive);
  train::TrainOptions pause = quiet();
  pause.overwrite = true;
  pause.stop_at = 2;
  {
    // While an eval reads an old round the new run is refused, and no round goes.
    const FolderLock evaluating(run.round_folder(2), "eval");
    expect_error_mentioning([&] { train::train_avatar(dataset, two_rounds, run, pause); },
                            "in use by another sfgs eval");
    EXPECT_TRUE(fs::exists(run.checkpoint_file()));
    EXPECT_TRUE(fs::exists(train::RunFolder{run.round_folder(1)}.checkpoint_file()));
  }
  train::train_avatar(dataset, two_rounds, run, pause);
  EXPECT_FALSE(fs::exists(run.checkpoint_file()));
  EXPECT_FALSE(fs::exists(run.round_folder(2)));
  EXPECT_EQ(train::CheckpointReader(train::RunFolder{run.round_folder(1)}.checkpoint_file()).info().iteration, 2);

  const std::vector<unsigned char> stored = read_bytes(run.config_file());
  train::TrainOptions resume = quiet();
  resume.resume = true;
  train::TrainConfig three_rounds = two_rounds, longer = two_rounds, wider = two_rounds;
  three_rounds.pose_refinement.rounds = 3;
  longer.schedule.iterations += 2;
  wider.avatar.hidden_width *= 2;
  train::TrainConfig one_round = two_rounds;
  one_round.pose_refinement.rounds = 1;
  expect_error([&] { train::train_avatar(dataset, three_rounds, run, resume); }, {"pose_refinement.rounds"});
  expect_error([&] { train::train_avatar(dataset, one_round, run, resume); }, {"pose_refinement.rounds"});
  expect_error([&] { train::train_avatar(dataset, longer, run, resume); }, {"iterations a round"});
  expect_error([&] { train::train_avatar(dataset, wider, run, resume); }, {"avatar.hidden_width"});
  train::TrainOptions other_start = resume;
  other_start.start_fits = reference.refined_fits_file();
  expect_error([&] { train::train_avatar(dataset, two_rounds, run, other_start); },
               {"round 1 started from other fits"});
  EXPECT_EQ(read_bytes(run.config_file()), stored);

  train::train_avatar(dataset, two_rounds, run, resume);
  EXPECT_EQ(read_bytes(run.refined_fits_file()), read_bytes(reference.refined_fits_file()));
}

}  // namespace
}  // namespace sfgs::testing
