// A run's results (train/results.h): files named by split, variant and dataset; provenance; a result refused when
// the checkpoint changed during its evaluation; stale results found and removed with the PNGs sfgs wrote, and
// nothing else a user keeps in the run folder.
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include <c10/util/Exception.h>
#include <gtest/gtest.h>

#include "train/results.h"

namespace sfgs::testing {
namespace {
namespace fs = std::filesystem;

void write(const fs::path& path, const std::string& text) { std::ofstream(path) << text; }

class TrainResults : public ::testing::Test {
 protected:
  void SetUp() override {
    folder_ = fs::temp_directory_path() / ("sfgs_results_" + std::to_string(::getpid()));
    fs::remove_all(folder_);
    fs::create_directories(folder_);
    run_.path = folder_.string();
    write(run_.checkpoint_file(), "checkpoint of iteration 2");
  }
  void TearDown() override { fs::remove_all(folder_); }

  train::ResultOrigin origin(data::Split split) const {
    train::ResultOrigin o;
    o.split = split;
    o.dataset = "/data/walk";
    o.dataset_fingerprint = "0a1b2c3d-10";
    o.checkpoint_iteration = 2;
    o.checkpoint_crc32 = train::checkpoint_digest(run_.checkpoint_file());
    o.command = "sfgs eval --run R";
    return o;
  }

  fs::path folder_;
  train::RunFolder run_;
};

TEST_F(TrainResults, FilesAreNamedBySplitVariantAndDataset) {
  train::ResultOrigin o = origin(data::Split::kVal);
  EXPECT_EQ(train::metrics_file_name(o), "metrics_val.json");
  EXPECT_EQ(train::images_folder_name(o), "eval_images_val");
  o.variant = "fitted_poses";
  EXPECT_EQ(train::metrics_file_name(o), "metrics_val_fitted_poses.json");
  o.own_dataset = false;
  EXPECT_EQ(train::metrics_file_name(o), "metrics_val_fitted_poses_0a1b2c3d-10.json");
}

TEST_F(TrainResults, RecordsProvenanceAndRefusesAResultOfAReplacedCheckpoint) {
  const std::string path = train::write_result(run_, origin(data::Split::kTest), {{"psnr", 30.0}});
  const nlohmann::json j = nlohmann::json::parse(std::ifstream(path));
  EXPECT_EQ(j["psnr"], 30.0);
  EXPECT_EQ(j["provenance"]["split"], "test");
  EXPECT_EQ(j["provenance"]["checkpoint_iteration"], 2);
  EXPECT_EQ(j["provenance"]["dataset_fingerprint"], "0a1b2c3d-10");
  EXPECT_TRUE(train::stale_results(run_, train::checkpoint_digest(run_.checkpoint_file())).empty());

  const train::ResultOrigin evaluated = origin(data::Split::kVal);
  write(run_.checkpoint_file(), "checkpoint of iteration 3");  // a training wrote it meanwhile
  EXPECT_THROW(train::write_result(run_, evaluated, {{"psnr", 31.0}}), c10::Error);
  EXPECT_FALSE(fs::exists(folder_ / "metrics_val.json"));
  EXPECT_EQ(train::stale_results(run_, train::checkpoint_digest(run_.checkpoint_file())),
            std::vector<std::string>{"metrics_test.json"});
}

TEST_F(TrainResults, RemovesStaleResultsWithTheirImagesOnly) {
  train::write_result(run_, origin(data::Split::kTest), {{"psnr", 30.0}});
  fs::create_directories(folder_ / "eval_images_test");
  write(folder_ / "eval_images_test" / "000001.png", "png");
  write(folder_ / "eval_images_test" / "notes.txt", "the user's");
  write(folder_ / "metrics.json", "{}");  // an older version's result: no provenance, so stale
  write(folder_ / "thesis.tex", "the user's");
  write(run_.checkpoint_file(), "checkpoint of iteration 3");
  std::vector<std::string> removed = train::remove_stale_results(run_);
  std::sort(removed.begin(), removed.end());
  EXPECT_EQ(removed, (std::vector<std::string>{"metrics.json", "metrics_test.json"}));
  EXPECT_FALSE(fs::exists(folder_ / "eval_images_test" / "000001.png"));
  EXPECT_TRUE(fs::exists(folder_ / "eval_images_test" / "notes.txt"));
  EXPECT_TRUE(fs::exists(folder_ / "thesis.tex"));
}

TEST_F(TrainResults, AFreshRunRemovesEveryDerivedOutput) {
  train::write_result(run_, origin(data::Split::kTest), {{"psnr", 30.0}});
  fs::create_directories(folder_ / "eval_images_val");
  write(folder_ / "eval_images_val" / "000002.png", "png");
  write(folder_ / "notes.txt", "the user's");
  train::remove_derived_outputs(run_);
  EXPECT_FALSE(fs::exists(folder_ / "metrics_test.json"));
  EXPECT_FALSE(fs::exists(folder_ / "eval_images_val"));
  EXPECT_TRUE(fs::exists(folder_ / "notes.txt"));
  EXPECT_TRUE(fs::exists(run_.checkpoint_file()));
}

}  // namespace
}  // namespace sfgs::testing
