// The trainer (csrc/train/trainer.h) on a tiny synthetic video: training lowers the loss and raises the training
// PSNR with every logged term non-negative and adding up to the total, a paused and resumed run ends bit-identical to
// an uninterrupted one, the run-time-versus-error curve holds every validation, and a run folder is never overwritten
// without being asked.
#include <cmath>
#include <fstream>
#include <functional>
#include <map>
#include <numeric>
#include <set>
#include <sstream>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <torch/serialize/input-archive.h>

#include "test_avatar_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "animate/animator.h"
#include "train/constants.h"
#include "train/evaluate.h"
#include "train/run_folder.h"
#include "train/rounds.h"
#include "train/trainer.h"

namespace sfgs::testing {
namespace {

// What 40 steps must achieve on the tiny video (measured: +0.55 dB and a ratio of 0.48).
constexpr double kMinimumPsnrGain = 0.3;   // dB on the training frames
constexpr double kMaximumLossRatio = 0.7;  // mean loss of the last five steps over the first five

data::Dataset ten_frame_video(const TempFolder& folder) { return testing::tiny_video(folder, 10, 32); }

// Every parameter and buffer of a run's checkpoint, by name ("avatar.<module path>"), with its top-level tensors.
// (LibTorch names the optimiser's state by parameter address, which differs between processes; a lost or wrong
// optimiser state shows instead in the losses after the resume.)
std::map<std::string, at::Tensor> checkpoint_tensors(const train::RunFolder& run) {
  torch::serialize::InputArchive archive;
  archive.load_from(run.checkpoint_file());
  std::map<std::string, at::Tensor> tensors;
  for (const std::string& key : archive.keys()) {
    at::Tensor t;
    if (archive.try_read(key, t)) tensors[key] = t;
  }
  const auto add_nested = [&](const std::string& name) {
    torch::serialize::InputArchive nested;
    archive.read(name, nested);
    std::function<void(torch::serialize::InputArchive&, const std::string&)> walk =
        [&](torch::serialize::InputArchive& a, const std::string& prefix) {
          for (const std::string& key : a.keys()) {
            at::Tensor t;
            if (a.try_read(key, t)) {
              tensors[prefix + key] = t;
            } else {
              torch::serialize::InputArchive inner;
              if (a.try_read(key, inner)) walk(inner, prefix + key + ".");
            }
          }
        };
    walk(nested, name + ".");
  };
  add_nested("avatar");
  return tensors;
}

// PSNR of a run's avatar on the training frames, as it stands at the run's checkpoint.
double training_psnr(const data::Dataset& dataset, const train::RunFolder& run) {
  train::TrainedAvatar trained = train::load_trained_avatar(run, at::kCPU);
  trained.avatar->eval();
  metrics::EvaluationOptions options;
  options.lpips_weights_dir.clear();
  return train::evaluate_avatar(dataset, data::Split::kTrain, trained.avatar, options, "", false).summary.psnr;
}

// Training must make the avatar better, and every loss term must pull the right way: a term whose sign is flipped
// either logs a negative value or no longer adds up to the total, and a flipped photometric term stops the PSNR
// from rising.
TEST(Trainer, TrainingLowersTheLossAndRaisesTheTrainingPsnr) {
  TempFolder folder;
  const data::Dataset dataset = ten_frame_video(folder);
  train::TrainConfig config = tiny_train_config();
  config.schedule.iterations = 40;
  config.schedule.learning_rate = config.schedule.colour_learning_rate = 3e-3;
  config.validate_every = 1000;
  train::TrainOptions options = quiet();
  const train::RunFolder run{folder / "run"};
  options.stop_at = 1;
  train::train_avatar(dataset, config, run, options);
  const double psnr_before = training_psnr(dataset, run);
  options.stop_at = 0;
  options.resume = true;
  train::train_avatar(dataset, config, run, options);
  const double psnr_after = training_psnr(dataset, run);
  EXPECT_GT(psnr_after, psnr_before + kMinimumPsnrGain) << "before " << psnr_before << " dB";

  std::vector<double> totals;
  for (const nlohmann::json& e : log_entries(run)) {
    if (e["event"] != "step") continue;
    double sum = 0;
    for (const auto& [name, value] : e["loss"].items()) {
      EXPECT_GE(value.get<double>(), 0.0) << name << " at iteration " << e["iteration"];
      if (name != "total" && name != "l1" && name != "ssim" && name != "lpips") sum += value.get<double>();
    }
    const double total = e["loss"]["total"].get<double>();
    EXPECT_NEAR(sum, total, 1e-5 * total) << "the terms do not add up to the total at iteration " << e["iteration"];
    totals.push_back(total);
  }
  ASSERT_EQ(totals.size(), 40u);
  const auto mean_of = [](auto first, auto last) { return std::accumulate(first, last, 0.0) / double(last - first); };
  EXPECT_LT(mean_of(totals.end() - 5, totals.end()), kMaximumLossRatio * mean_of(totals.begin(), totals.begin() + 5));
}

TEST(Trainer, ResumedRunEqualsUninterruptedRun) {
  TempFolder folder;
  const data::Dataset dataset = ten_frame_video(folder);
  const train::TrainConfig config = tiny_train_config();
  train::TrainOptions quiet;
  quiet.progress = false;

  const train::RunFolder straight{folder / "straight"}, paused{folder / "paused"};
  const train::TrainSummary whole = train::train_avatar(dataset, config, straight, quiet);
  EXPECT_EQ(whole.iterations, 6);

  train::TrainOptions pause = quiet;
  pause.stop_at = 3;
  EXPECT_EQ(train::train_avatar(dataset, config, paused, pause).iterations, 3);
  train::TrainOptions resume = quiet;
  resume.resume = true;
  EXPECT_EQ(train::train_avatar(dataset, config, paused, resume).iterations, 6);

  const auto a = checkpoint_tensors(straight), b = checkpoint_tensors(paused);
  ASSERT_EQ(a.size(), b.size());
  int64_t parameters = 0;
  for (const auto& [key, tensor] : a) {
    // Wall time differs; the optimiser's serialised state names parameters by address, which differs between
    // processes (and so does its checksum): a lost or wrong optimiser state shows in the losses below instead.
    if (key == "training_seconds" || key == "optimizer_state" || key == "checksums") continue;
    ASSERT_TRUE(b.count(key)) << key;
    EXPECT_TRUE(tensor.equal(b.at(key))) << key;
    parameters += key.rfind("avatar.", 0) == 0 ? 1 : 0;
  }
  EXPECT_GT(parameters, 20);
  // Every logged step after the pause has the loss of the uninterrupted run's step.
  const auto losses = [](const train::RunFolder& run) {
    std::map<int64_t, double> by_iteration;
    for (const nlohmann::json& e : log_entries(run))
      if (e["event"] == "step") by_iteration[e["iteration"].get<int64_t>()] = e["loss"]["total"].get<double>();
    return by_iteration;
  };
  const auto straight_losses = losses(straight), paused_losses = losses(paused);
  ASSERT_EQ(straight_losses.size(), 6u);
  EXPECT_EQ(straight_losses, paused_losses);
  // Training changed the avatar: the resumed run did not just reload the paused state.
  const train::RunFolder short_run{folder / "short"};
  train::TrainConfig three = config;
  three.schedule.iterations = 3;
  train::train_avatar(dataset, three, short_run, quiet);
  bool moved = false;
  for (const auto& [key, tensor] : checkpoint_tensors(short_run))
    moved = moved || (key.rfind("avatar.", 0) == 0 && !tensor.equal(a.at(key)));
  EXPECT_TRUE(moved);
}

TEST(Trainer, ErrorCurveHoldsEveryValidation) {
  TempFolder folder;
  const data::Dataset dataset = ten_frame_video(folder);
  train::TrainOptions quiet;
  quiet.progress = false;
  const train::RunFolder run{folder / "run"};
  train::TrainOptions pause = quiet;
  pause.stop_at = 4;
  train::train_avatar(dataset, tiny_train_config(), run, pause);
  train::TrainOptions resume = quiet;
  resume.resume = true;
  train::train_avatar(dataset, tiny_train_config(), run, resume);

  const auto points = train::write_error_curve_csv(run, folder / "curve.csv");
  ASSERT_EQ(points.size(), 3u);  // iterations 2, 4 and 6; the resume does not duplicate 4
  double seconds = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    EXPECT_EQ(points[i].iteration, int64_t(2 * (i + 1)));
    EXPECT_GT(points[i].training_seconds, seconds);  // training time accumulates across the resume
    seconds = points[i].training_seconds;
    EXPECT_TRUE(std::isfinite(points[i].val_psnr));
    EXPECT_TRUE(std::isfinite(points[i].test_psnr));
    EXPECT_GT(points[i].test_psnr, 5.0);
  }
  std::ifstream csv(folder / "curve.csv");
  std::string header, row;
  std::getline(csv, header);
  EXPECT_EQ(header, "iteration,training_seconds,val_psnr,test_psnr");
  int rows = 0;
  while (std::getline(csv, row)) rows += !row.empty();
  EXPECT_EQ(rows, 3);
}

TEST(Trainer, NeverOverwritesARunUnasked) {
  TempFolder folder;
  const data::Dataset dataset = ten_frame_video(folder);
  train::TrainConfig config = tiny_train_config();
  config.schedule.iterations = 1;
  train::TrainOptions quiet;
  quiet.progress = false;
  const train::RunFolder run{folder / "run"};
  train::train_avatar(dataset, config, run, quiet);
  std::ifstream before(run.checkpoint_file(), std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(before)), std::istreambuf_iterator<char>());
  expect_error_mentioning([&] { train::train_avatar(dataset, config, run, quiet); }, "--resume");
  std::ifstream after(run.checkpoint_file(), std::ios::binary);
  EXPECT_EQ(bytes, std::string((std::istreambuf_iterator<char>(after)), std::istreambuf_iterator<char>()));
  train::TrainOptions bad = quiet;
  bad.resume = true;
  bad.stop_at = 1;
  config.schedule.iterations = 3;
  expect_error_mentioning([&] { train::train_avatar(dataset, config, run, bad); }, "it is already at iteration 1");
}

// `sfgs eval` renders frames ahead of their metrics in chunks: every frame must still be scored against its own
// image, across the chunks' boundaries, as a render of that frame alone would be.
TEST(TrainEvaluation, EveryFrameScoresAsItsRenderAlone) {
  TempFolder folder;
  data::Dataset video = tiny_video(folder, 28, 32);
  model::Avatar avatar = render_frames_with_avatar(video, {0, 1});
  const std::vector<int64_t>& frames = video.split(data::Split::kTrain);
  ASSERT_GT(frames.size(), size_t(kFramesRenderedAhead)) << "the split must span more than one chunk";
  metrics::EvaluationOptions options;
  options.lpips_weights_dir.clear();
  const train::AvatarEvaluation evaluation =
      train::evaluate_avatar(video, data::Split::kTrain, avatar, options, "", false);
  ASSERT_EQ(evaluation.frames.size(), frames.size());
  at::NoGradGuard no_grad;
  metrics::ImageEvaluator alone(options);
  animate::Animator animator(avatar, train::render_camera(video.frames[size_t(frames.front())]), at::ones({3}));
  std::set<double> scores;
  for (size_t i = 0; i < frames.size(); ++i) {
    const data::FrameRecord& record = video.frames[size_t(frames[i])];
    animator.set_camera(train::render_camera(record));
    const at::Tensor image = animator.render(record.pose, video.replay_time(frames[i])).clone();
    const data::Frame frame = video.load(frames[i]);
    const metrics::FrameMetrics expected = alone.add_frame(image, frame.image, frame.eval_mask);
    EXPECT_EQ(evaluation.frame_names[i], record.name);
    EXPECT_EQ(evaluation.frames[i].psnr, expected.psnr) << "frame " << record.name;
    EXPECT_EQ(evaluation.frames[i].ssim, expected.ssim) << "frame " << record.name;
    scores.insert(expected.psnr);
  }
  EXPECT_GT(scores.size(), frames.size() / 2) << "frames that score alike could not tell a mix-up";
}

}  // namespace
}  // namespace sfgs::testing
