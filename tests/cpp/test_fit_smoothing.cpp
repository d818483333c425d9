// Temporal smoothing of a video's fits (train/fit_smoothing.h): a steadily accelerating motion passes unchanged, each
// row keeping its own axis-angle representative across a half turn; frame-to-frame jitter shrinks; sequences do not
// mix and a frame alone in its window keeps its fit; pose refinement smooths the input fits of its training frames;
// bad arguments are refused by name.
#include <cmath>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "body/rotations.h"
#include "test_body_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/fit_smoothing.h"
#include "train/pose_refinement.h"

namespace sfgs::testing {
namespace {

constexpr double kSigma = 0.1;  // seconds: 3 frames at 30 fps

// Frame times of a 30 fps video with every fifth frame held out (the interleaved test frames).
std::vector<double> interleaved_times(int64_t frames) {
  std::vector<double> t;
  for (int64_t k = 0; t.size() < size_t(frames); ++k)
    if (k % 5 != 4) t.push_back(double(k) / 30);
  return t;
}

// Rows of R = 3 rotations about fixed axes, each angle quadratic in time, and a quadratic translation. The first
// rotation is a camera-frame root near a half turn about x, written with the representative an estimator might pick
// (alternately 3.1 and -3.18 rad about x for the same turn).
at::Tensor accelerating_motion(const std::vector<double>& t) {
  const int64_t frames = int64_t(t.size());
  at::Tensor rows = at::zeros({frames, 12}, at::kDouble);
  const double axes[3][3] = {{1, 0, 0}, {0, 0.6, 0.8}, {0.48, 0.6, -0.64}};
  for (int64_t f = 0; f < frames; ++f) {
    const double s = t[size_t(f)];
    const double angles[3] = {M_PI - 0.3 + 0.4 * s + 0.9 * s * s, 0.2 - 1.5 * s + 2.0 * s * s, -0.4 + 0.7 * s};
    for (int j = 0; j < 3; ++j) {
      const double angle = j == 0 && f % 2 == 1 && angles[0] > M_PI ? angles[0] - 2 * M_PI : angles[j];
      for (int c = 0; c < 3; ++c) rows[f][3 * j + c] = angle * axes[j][c];
    }
    rows[f][9] = 0.1 + 0.3 * s - 0.2 * s * s;
    rows[f][10] = -0.05 * s * s;
    rows[f][11] = 2.6 + 0.1 * s;
  }
  return rows;
}

TEST(FitSmoothing, KeepsASteadilyAcceleratingMotionAndEachRowsRepresentative) {
  const std::vector<double> t = interleaved_times(40);
  const at::Tensor rows = accelerating_motion(t);
  ASSERT_GT(rows.select(1, 0).max().item<double>(), M_PI - 0.3);
  ASSERT_LT(rows.select(1, 0).min().item<double>(), -M_PI + 0.3) << "the root crosses the half turn";
  const at::Tensor smoothed = train::smooth_fits(rows, 3, t, std::vector<int64_t>(t.size(), 0), kSigma);
  EXPECT_LT((smoothed - rows).abs().max().item<double>(), 1e-9);
  EXPECT_EQ(smoothed.scalar_type(), at::kDouble);
  const at::Tensor single = train::smooth_fits(rows.to(at::kFloat), 3, t, std::vector<int64_t>(t.size(), 0), kSigma);
  EXPECT_EQ(single.scalar_type(), at::kFloat);
  EXPECT_LT((single.to(at::kDouble) - rows).abs().max().item<double>(), 1e-5);
}

TEST(FitSmoothing, TakesOutFrameToFrameJitter) {
  const std::vector<double> t = interleaved_times(60);
  const at::Tensor truth = accelerating_motion(t);
  at::Tensor jitter = at::empty_like(truth).normal_(0.0, 0.035, at::make_generator<at::CPUGeneratorImpl>(7));
  const at::Tensor smoothed = train::smooth_fits(truth + jitter, 3, t, std::vector<int64_t>(t.size(), 0), kSigma);
  // The rotations' error as turns (a difference of axis-angles across the half turn would read 2 pi).
  const auto error = [&](const at::Tensor& rows) {
    const at::Tensor a = body::axis_angle_to_matrix(rows.narrow(1, 0, 9).reshape({-1, 3}));
    const at::Tensor b = body::axis_angle_to_matrix(truth.narrow(1, 0, 9).reshape({-1, 3}));
    const at::Tensor turns = body::matrix_to_axis_angle(a.transpose(1, 2).matmul(b));
    return std::make_pair(turns.pow(2).sum(1).mean().sqrt().item<double>(),
                          (rows.narrow(1, 9, 3) - truth.narrow(1, 9, 3)).pow(2).sum(1).mean().sqrt().item<double>());
  };
  const auto [rotation_before, translation_before] = error(truth + jitter);
  const auto [rotation_after, translation_after] = error(smoothed);
  EXPECT_LT(rotation_after, 0.6 * rotation_before) << rotation_before << " rad RMS before";
  EXPECT_LT(translation_after, 0.6 * translation_before) << translation_before << " m RMS before";
}

TEST(FitSmoothing, SequencesDoNotMixAndAFrameAloneKeepsItsFit) {
  // Two sequences at the same times, each holding its own pose: smoothing across them would blend the two.
  const std::vector<double> t = interleaved_times(12);
  std::vector<double> times = t;
  times.insert(times.end(), t.begin(), t.end());
  std::vector<int64_t> sequences(t.size(), 0);
  sequences.resize(2 * t.size(), 1);
  at::Tensor rows = at::zeros({int64_t(times.size()), 6}, at::kDouble);
  rows.narrow(0, 0, int64_t(t.size())).fill_(0.2);
  rows.narrow(0, int64_t(t.size()), int64_t(t.size())).fill_(-0.4);
  EXPECT_LT((train::smooth_fits(rows, 1, times, sequences, kSigma) - rows).abs().max().item<double>(), 1e-12);
  // Frames a second apart: none has another within the window, so nothing moves however they jitter.
  const at::Tensor sparse = at::rand({5, 6}, at::kDouble);
  const std::vector<double> seconds{0, 1, 2, 3, 4};
  EXPECT_TRUE(train::smooth_fits(sparse, 1, seconds, std::vector<int64_t>(5, 0), kSigma).equal(sparse));
  EXPECT_TRUE(train::smooth_fits(sparse, 1, {0, 0.03, 0.07, 0.1, 0.13}, std::vector<int64_t>(5, 0), 0).equal(sparse))
      << "sigma 0: no smoothing";
  // Two frames only: a line through them, which is each of them.
  const at::Tensor pair = at::rand({2, 6}, at::kDouble);
  EXPECT_LT((train::smooth_fits(pair, 1, {0, 0.033}, {0, 0}, kSigma) - pair).abs().max().item<double>(), 1e-9);
}

TEST(FitSmoothing, BadArgumentsAreRefused) {
  const at::Tensor rows = at::zeros({4, 6});
  const std::vector<double> t{0, 0.03, 0.07, 0.1};
  const std::vector<int64_t> s(4, 0);
  expect_error([&] { train::smooth_fits(at::zeros({4, 5}), 2, t, s, kSigma); }, {"(F, 3 R + L)", "R = 2"});
  expect_error([&] { train::smooth_fits(rows, 1, {0, 1}, s, kSigma); }, {"4 fits", "2 and 4"});
  expect_error([&] { train::smooth_fits(rows, 1, t, s, -1); }, {"sigma_seconds", "-1"});
  expect_error([&] { train::smooth_fits(rows, 1, t, s, NAN); }, {"sigma_seconds", "nan"});
}

// Pose refinement with smoothing_seconds smooths its training frames' input fits before any pass (and the fits each
// pass leaves): on fits that jitter about the truth, the refined fits it starts from lie nearer the truth than the
// input. Without it (the default) they are the input.
TEST(FitSmoothing, PoseRefinementStartsFromTheSmoothedFits) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 30, 16);
  const auto generator = at::make_generator<at::CPUGeneratorImpl>(3);
  for (const int64_t f : dataset.split(data::Split::kTrain)) {
    body::SmplxPose& pose = dataset.frames[size_t(f)].pose;
    dataset.frames[size_t(f)].true_pose = pose;
    pose.body_pose = pose.body_pose + at::empty_like(pose.body_pose).normal_(0.0, 0.05, generator);
    pose.transl = pose.transl + at::empty_like(pose.transl).normal_(0.0, 0.02, generator);
  }
  train::PoseRefinementConfig config;
  config.enabled = true;
  config.smoothing_seconds = kSigma;
  const nlohmann::json error = train::PoseRefinement(dataset, config, 100, at::kCPU, nullptr).error_against_truth();
  for (const char* key : {"body_deg", "translation_cm"})
    EXPECT_LT(error.at("refined").at(key).get<double>(), 0.75 * error.at("input").at(key).get<double>()) << key;
  config.smoothing_seconds = train::PoseRefinementConfig{}.smoothing_seconds;
  const nlohmann::json unsmoothed =
      train::PoseRefinement(dataset, config, 100, at::kCPU, nullptr).error_against_truth();
  EXPECT_EQ(unsmoothed.at("refined"), unsmoothed.at("input"));
}

}  // namespace
}  // namespace sfgs::testing
