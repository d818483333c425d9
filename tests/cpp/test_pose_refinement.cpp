// Pose refinement in training and test-time pose fitting (train/pose_refinement.h): a correction adds exactly to
// its fields; the prior pulls a correction back to the input fit and the smoothness term evens out a jittered frame;
// the image's gradient reaches the corrections of a real training run, whose refined fits are saved, applied to its
// training frames only and resumed exactly; a fit recovers a perturbed pose from the avatar's own image; bad
// refined-fits files are refused by name.
#include <cmath>
#include <fstream>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "data/image_io.h"
#include "test_avatar_utils.h"
#include "test_body_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/checkpoint.h"
#include "train/pose_refinement.h"
#include "train/run_folder.h"
#include "train/trainer.h"

namespace sfgs::testing {
namespace {

using train::kCorrectionWidth;

train::PoseRefinementConfig refinement(double prior, double smoothness) {
  train::PoseRefinementConfig c;
  c.enabled = true;
  c.start = 0;
  c.prior = prior;
  c.smoothness = smoothness;
  c.learning_rate = 1e-2;
  return c;
}

// Steps frame f's correction `steps` times on its regularisers alone (no image).
void step_on_regularisers(train::PoseRefinement& r, int64_t f, int steps) {
  for (int k = 0; k < steps; ++k) {
    train::LossTerms terms;
    r.pose(f, 0, terms);
    train::total_loss(terms).backward();
    r.step(f, 0, 1.0);
  }
}

TEST(TrainPoseRefinement, CorrectionAddsToItsFieldsOnly) {
  body::SmplxPose base = test_pose(41, 0.3, true);
  const at::Tensor correction = at::arange(kCorrectionWidth, at::kFloat) * 1e-3;
  const body::SmplxPose p = train::corrected_pose(base, correction);
  EXPECT_LT(max_abs_difference(p.global_orient, base.global_orient + correction.narrow(0, 0, 3)), 1e-7);
  EXPECT_LT(max_abs_difference(p.body_pose.reshape({-1}), base.body_pose.reshape({-1}) + correction.narrow(0, 3, 63)),
            1e-7);
  EXPECT_LT(max_abs_difference(p.right_hand_pose.reshape({-1}),
                               base.right_hand_pose.reshape({-1}) + correction.narrow(0, 114, 45)),
            1e-7);
  EXPECT_LT(max_abs_difference(p.transl, base.transl + correction.narrow(0, kCorrectionWidth - 3, 3)), 1e-7);
  EXPECT_TRUE(p.expression.equal(base.expression)) << "the expression is not corrected";
  base.left_hand_pose = at::Tensor();
  EXPECT_FALSE(train::corrected_pose(base, correction).left_hand_pose.defined()) << "an absent hand stays absent";
  expect_error([&] { train::corrected_pose(base, at::zeros({5})); }, {"162 values"});
}

TEST(TrainPoseRefinement, PriorPullsACorrectionBackToTheFit) {
  TempFolder folder;
  const data::Dataset dataset = tiny_video(folder, 10, 16);
  train::PoseRefinement r(dataset, refinement(1.0, 0.0), 100, at::kCPU);
  const int64_t f = dataset.split(data::Split::kTrain)[2];
  at::Tensor state = r.state();
  state.narrow(1, 0, kCorrectionWidth).fill_(0.05);
  r.restore(state);
  step_on_regularisers(r, f, 30);
  const at::Tensor after = r.state().narrow(1, 0, kCorrectionWidth);
  const std::vector<int64_t>& train_frames = dataset.split(data::Split::kTrain);
  const int64_t row = std::find(train_frames.begin(), train_frames.end(), f) - train_frames.begin();
  EXPECT_LT(after[row].abs().mean().item<double>(), 0.02) << "pulled towards the input fit (from 0.05)";
  const at::Tensor others = at::cat({after.narrow(0, 0, row), after.narrow(0, row + 1, after.size(0) - row - 1)});
  EXPECT_LT((others - 0.05).abs().max().item<double>(), 1e-6) << "the other frames' corrections did not move";
}

TEST(TrainPoseRefinement, SmoothnessEvensOutAJitteredFrame) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 10, 16);
  const std::vector<int64_t>& train_frames = dataset.split(data::Split::kTrain);
  const int64_t f = train_frames[3];
  dataset.frames[size_t(f)].pose.body_pose = dataset.frames[size_t(f)].pose.body_pose + 0.1;  // an estimator's jump
  train::PoseRefinement r(dataset, refinement(0.0, 1.0), 100, at::kCPU);
  const auto jump = [&](const data::Dataset& d) {
    const auto body = [&](int64_t k) { return d.frames[size_t(train_frames[size_t(k)])].pose.body_pose; };
    return (body(3) - 0.5 * (body(2) + body(4))).abs().mean().item<double>();
  };
  const double before = jump(dataset);
  step_on_regularisers(r, f, 60);
  TempFolder out;
  r.write_fits(out / "fits.json");
  data::Dataset refined = dataset;
  train::apply_refined_fits(refined, out / "fits.json");
  EXPECT_LT(jump(refined), 0.3 * before) << "before " << before;
}

// A real (tiny) training run: the image's gradient moves the corrections of the frames it drew, the refined fits
// land in the run folder and on its training frames (not on the others), and a paused and resumed run refines to
// exactly the same corrections.
TEST(TrainPoseRefinement, TrainingRefinesSavesAndResumesTheFits) {
  TempFolder folder;
  const data::Dataset dataset = tiny_video(folder, 10, 32);
  train::TrainConfig config = tiny_train_config();
  config.pose_refinement = refinement(0.01, 0.05);
  config.pose_refinement.start = 0.5;  // the corrections start moving in the middle of the run, at the pause
  const train::RunFolder whole{folder / "whole"}, paused{folder / "paused"};
  train::train_avatar(dataset, config, whole, quiet());
  train::TrainOptions pause = quiet();
  pause.stop_at = 3;
  train::train_avatar(dataset, config, paused, pause);
  train::TrainOptions resume = quiet();
  resume.resume = true;
  train::train_avatar(dataset, config, paused, resume);

  const at::Tensor state = train::CheckpointReader(whole.checkpoint_file()).info().pose_refinement;
  ASSERT_TRUE(state.defined());
  const at::Tensor corrections = state.narrow(1, 0, kCorrectionWidth);
  EXPECT_TRUE(corrections.isfinite().all().item<bool>());
  EXPECT_GT(corrections.abs().max().item<double>(), 0.0) << "the image's gradient reached the corrections";
  EXPECT_TRUE(state.equal(train::CheckpointReader(paused.checkpoint_file()).info().pose_refinement))
      << "a resumed run refines exactly as an uninterrupted one";

  const train::TrainedAvatar trained = train::load_trained_avatar(whole, at::kCPU);
  ASSERT_FALSE(trained.refined_fits.empty());
  const data::Dataset used = train::read_run_dataset(trained, "");
  int64_t changed = 0;
  for (int64_t f = 0; f < dataset.size(); ++f) {
    const bool differs = !used.frames[size_t(f)].pose.body_pose.equal(dataset.frames[size_t(f)].pose.body_pose);
    const auto& train_frames = dataset.split(data::Split::kTrain);
    if (std::find(train_frames.begin(), train_frames.end(), f) == train_frames.end()) {
      EXPECT_FALSE(differs) << "frame " << f << " was not trained on";
    } else {
      changed += differs;
    }
  }
  EXPECT_GT(changed, 0);
}

// The avatar's own render of a pose is the target; the frame's fit is turned by 0.25 rad about the vertical, its
// hips by 0.2 rad, and shifted 8 cm sideways (a few pixels each at 64 x 64). Fitting with the avatar frozen must more
// than halve the image's error and bring the perturbed parameters closer (every joint is free, so others share the
// correction at this size).
TEST(TrainPoseFitting, RecoversAPerturbedPoseFromTheAvatarsImage) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 10, 64);
  model::Avatar avatar(procedural_avatar_body(), dataset.betas, small_config());
  randomise_parameters(*avatar, 0.3, 42);  // a textured avatar: colours that vary over the body
  avatar->eval();
  avatar->cache_static_features();
  const int64_t f = dataset.split(data::Split::kTest)[0];
  data::FrameRecord& record = dataset.frames[size_t(f)];
  const body::SmplxPose truth = record.pose;
  {
    at::NoGradGuard no_grad;
    const model::AvatarOutput out = avatar->forward(truth, dataset.replay_time(f));
    const RenderResult r = render(model::to_gaussians(out), at::ones({3}), train::render_camera(record));
    data::write_png(record.image_path, r.image, true);
    record.mask_path.clear();  // the whole image is the target
  }
  const at::Tensor hips = at::zeros({21, 3});
  hips.narrow(0, 0, 2).select(1, 0).fill_(0.2);  // body_pose rows 0 and 1: the left and right hips
  record.pose.global_orient = truth.global_orient + at::tensor({0.f, 0.25f, 0.f});
  record.pose.body_pose = truth.body_pose + hips;
  record.pose.transl = truth.transl + at::tensor({0.08f, 0.f, 0.f});
  const auto error = [&](const body::SmplxPose& p) {
    return (p.global_orient - truth.global_orient).abs().sum().item<double>() +
           (p.body_pose - truth.body_pose).narrow(0, 0, 2).abs().sum().item<double>() +
           (p.transl - truth.transl).abs().sum().item<double>();
  };
  train::PoseFitOptions options;
  options.iterations = 25;
  options.learning_rate = 2e-2;
  options.translation_learning_rate = 1e-2;
  options.loss.use_lpips = false;
  const data::Dataset fitted = train::fit_poses(dataset, data::Split::kTest, avatar, options, false);
  const double before = error(record.pose), after = error(fitted.frames[size_t(f)].pose);
  EXPECT_LT(after, before) << "pose error before " << before << ", after " << after;
  const auto image_error = [&](const body::SmplxPose& p) {
    at::NoGradGuard no_grad;
    const model::AvatarOutput out = avatar->forward(p, dataset.replay_time(f));
    const RenderResult r = render(model::to_gaussians(out), at::ones({3}), train::render_camera(record));
    return (r.image - dataset.load(f).image).abs().mean().item<double>();
  };
  const double image_before = image_error(record.pose), image_after = image_error(fitted.frames[size_t(f)].pose);
  EXPECT_LT(image_after, 0.5 * image_before) << "image error before " << image_before << ", after " << image_after;
  EXPECT_TRUE(fitted.frames[size_t(f)].pose.non_finite().empty());
  const int64_t other = dataset.split(data::Split::kTrain)[0];
  EXPECT_TRUE(fitted.frames[size_t(other)].pose.body_pose.equal(dataset.frames[size_t(other)].pose.body_pose))
      << "frames of other splits keep their fits";
}

TEST(TrainPoseRefinement, BadRefinedFitsFilesAreRefused) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 10, 16);
  const auto write = [&](const std::string& name, const nlohmann::json& j) {
    std::ofstream(folder / name) << j.dump();
    return folder / name;
  };
  expect_error([&] { train::apply_refined_fits(dataset, write("a.json", {{"format", "other"}})); },
               {"a.json", "refined-fits"});
  const std::string frame = dataset.frames[0].name;
  expect_error([&] {
    train::apply_refined_fits(dataset, write("b.json", {{"format", "sfgs-refined-fits"},
                                                        {"frames", {{frame, {{"global_orient", {0, 0, 0}}}}}}}));
  }, {"b.json", frame, "body_pose"});
}

}  // namespace
}  // namespace sfgs::testing
