// A second round (train/trainer.h TrainOptions::start_fits): a run whose training frames start from an earlier run's
// refined fits trains on them, keeps them through a pause and a resume (the resumed dataset's fingerprint would differ
// without them) and gives them, under its own refined fits, to every command reading it; a resume from other fits,
// fits that name no training frame or a frame that is not one are refused; a new run in the same folder without them
// trains on the dataset's own fits, and a start-fits copy left beside such a run does not change what it reads.
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "test_body_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/pose_refinement.h"
#include "train/run_folder.h"
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

TEST(TrainPoseRefinement, ASecondRoundStartsFromAnEarlierRunsRefinedFits) {
  TempFolder folder;
  const data::Dataset dataset = tiny_video(folder, 10, 32);
  train::TrainConfig refining = tiny_train_config();
  refining.pose_refinement.enabled = true;
  refining.pose_refinement.align_at = {0.5};
  refining.pose_refinement.align_iterations = 4;
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

}  // namespace
}  // namespace sfgs::testing
