// Pose refinement in training and test-time pose fitting (train/pose_refinement.h): a correction adds exactly to
// its fields; the prior pulls a correction back to the input fit and the smoothness term evens out a jittered frame;
// the image's gradient reaches the corrections of a real training run, whose refined fits are saved, applied to its
// training frames only and resumed exactly; a fit recovers a perturbed pose from the avatar's own image and stays at
// an exact one; the alignment of training fits brings them to the truth; bad refined-fits files and alignment
// settings are refused by name (a second round's start fits: test_second_round.cpp).
#include <algorithm>
#include <cmath>
#include <fstream>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "data/image_io.h"
#include "test_avatar_utils.h"
#include "test_body_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "data/keypoint_file.h"
#include "data/synthetic.h"
#include "train/avatar_keypoints.h"
#include "train/checkpoint.h"
#include "train/pose_fit.h"
#include "train/pose_refinement.h"
#include "train/run_folder.h"
#include "train/rounds.h"
#include "train/trainer.h"

namespace sfgs::testing {
namespace {

using train::kCorrectionWidth;

// Pose refinement on, with one short alignment pass in the middle of a run.
train::PoseRefinementConfig refinement() {
  train::PoseRefinementConfig c;
  c.enabled = true;
  c.start = 0.2;
  c.align_at = {0.5};
  c.align_iterations = 4;
  return c;
}

// A video of the procedural body whose keypoint files hold the exact projections (score 1).
data::Dataset video_with_exact_keypoints(const TempFolder& folder, int64_t frames, int64_t side) {
  data::SyntheticVideoOptions o;
  o.frames = frames;
  o.width = side;
  o.height = side;
  o.keypoint_noise.exact = true;
  return data::write_synthetic_video(folder / "video", o);
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

// The steps train the avatar on the fits as the last alignment pass left them: a frame's pose is its fit plus its
// correction, with no gradient, and in a training run the steps log no pose term while the alignment pass moves the
// fits.
TEST(TrainPoseRefinement, StepsTrainOnTheFitsTheLastAlignmentLeft) {
  TempFolder folder;
  const data::Dataset dataset = video_with_exact_keypoints(folder, 10, 64);
  const body::WholeBodyKeypointMap map = train::body_keypoint_map("");
  const train::PoseRefinementConfig config = refinement();
  train::PoseRefinement r(dataset, config, 100, at::kCPU, &map);
  const int64_t f = dataset.split(data::Split::kTrain)[1];
  at::Tensor state = r.state();
  ASSERT_EQ(state.sizes(), at::IntArrayRef({int64_t(dataset.split(data::Split::kTrain).size()), kCorrectionWidth}));
  state[1][3] = 0.05;  // the first body joint's x, as a pass might have left it
  r.restore(state);
  const body::SmplxPose pose = r.fit(f);
  EXPECT_FALSE(pose.body_pose.requires_grad());
  const body::SmplxPose& given = dataset.frames[size_t(f)].pose;
  EXPECT_NEAR((pose.body_pose[0][0] - given.body_pose[0][0]).item<double>(), 0.05, 1e-6);
  EXPECT_TRUE(pose.global_orient.equal(given.global_orient.reshape({-1})));
  // A checkpoint of a version with per-step corrections held their Adam moments and step counts after them.
  train::PoseRefinement older(dataset, config, 100, at::kCPU, &map);
  older.restore(at::cat({state, at::ones({state.size(0), 2 * kCorrectionWidth + 1}, state.options())}, 1));
  EXPECT_TRUE(older.state().equal(r.state()));
  expect_error([&] { older.restore(state.narrow(1, 0, 5)); }, {"expected (", "162)"});

  train::TrainConfig run_config = tiny_train_config();
  run_config.pose_refinement = config;
  const train::RunFolder run{folder / "run"};
  train::train_avatar(dataset, run_config, run, quiet());
  int64_t steps = 0;
  for (const nlohmann::json& entry : log_entries(run)) {
    if (entry.value("event", "") != "step") continue;
    ++steps;
    for (const char* term : {"pose_prior", "pose_smoothness", "pose_keypoints"})
      EXPECT_FALSE(entry.at("loss").contains(term)) << term << " at iteration " << entry.at("iteration");
  }
  EXPECT_GT(steps, 0);
  const at::Tensor moved = train::CheckpointReader(run.checkpoint_file()).info().pose_refinement;
  ASSERT_TRUE(moved.defined());
  EXPECT_GT(moved.abs().max().item<double>(), 0.0) << "the pass moved no fit";
}

// A real (tiny) training run: the alignment pass happens once, where align_at says, and is logged; the refined fits
// land in the run folder and on its training frames (not on the others); a run paused before or after the pass and
// resumed refines to exactly the same corrections.
TEST(TrainPoseRefinement, TrainingRefinesSavesAndResumesTheFits) {
  TempFolder folder;
  const data::Dataset dataset = tiny_video(folder, 10, 32);
  train::TrainConfig config = tiny_train_config();
  config.pose_refinement = refinement();
  const train::RunFolder whole{folder / "whole"};
  train::train_avatar(dataset, config, whole, quiet());
  std::vector<int64_t> alignments;
  for (const nlohmann::json& entry : log_entries(whole))
    if (entry.value("event", "") == "pose_alignment") alignments.push_back(entry.at("iteration").get<int64_t>());
  EXPECT_EQ(alignments, std::vector<int64_t>{3}) << "the training fits were aligned once, at iteration 3";
  const at::Tensor state = train::CheckpointReader(whole.checkpoint_file()).info().pose_refinement;
  ASSERT_TRUE(state.defined());
  EXPECT_TRUE(state.isfinite().all().item<bool>());
  EXPECT_GT(state.abs().max().item<double>(), 0.0) << "the pass moved the fits";
  // Paused before the pass (the checkpoint's observation record does not reach the avatar the pass fits against)
  // and after it, and resumed.
  for (const int64_t stop : {2, 4}) {
    const train::RunFolder paused{folder / ("paused" + std::to_string(stop))};
    train::TrainOptions pause = quiet();
    pause.stop_at = stop;
    train::train_avatar(dataset, config, paused, pause);
    train::TrainOptions resume = quiet();
    resume.resume = true;
    train::train_avatar(dataset, config, paused, resume);
    EXPECT_TRUE(state.equal(train::CheckpointReader(paused.checkpoint_file()).info().pose_refinement))
        << "a run paused at " << stop << " refines as an uninterrupted one";
  }

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

// A fit turned by `turn` rad about the vertical, its hips bent by `hips` rad, shifted `shift` m sideways and
// `depth` m along z.
body::SmplxPose perturbed(const body::SmplxPose& truth, float turn, float hips, float shift, float depth) {
  body::SmplxPose p = truth;
  const at::Tensor bend = at::zeros({21, 3});
  bend.narrow(0, 0, 2).select(1, 0).fill_(hips);  // body_pose rows 0 and 1: the left and right hips
  p.global_orient = truth.global_orient + at::tensor({0.f, turn, 0.f});
  p.body_pose = truth.body_pose + bend;
  p.transl = truth.transl + at::tensor({shift, 0.f, depth});
  return p;
}

// The first test frame of `dataset` as the target of a fit: rendered by a random-parameter avatar (returned), its
// fit perturbed as `perturbed` says (by default turned 0.1 rad, hips bent 0.15 rad, shifted 4 cm sideways); the exact
// fit is returned beside it.
struct PerturbedFrame {
  int64_t frame;
  model::Avatar avatar;
  body::SmplxPose truth;
};
PerturbedFrame perturbed_test_frame(data::Dataset& dataset, float turn = 0.1f, float hips = 0.15f, float shift = 0.04f,
                                    float depth = 0.0f) {
  const int64_t f = dataset.split(data::Split::kTest)[0];
  model::Avatar avatar = render_frames_with_avatar(dataset, {f});
  data::FrameRecord& record = dataset.frames[size_t(f)];
  const body::SmplxPose truth = record.pose;
  record.pose = perturbed(truth, turn, hips, shift, depth);
  return {f, avatar, truth};
}

train::PoseFitOptions fit_options(int64_t iterations) {
  train::PoseFitOptions options;
  options.iterations = iterations;
  options.loss.use_lpips = false;
  return options;
}

// The avatar's own render is the target, so the truth is the image loss's minimum; the frame's fit is turned by
// 0.1 rad, its hips bent by 0.15 rad and shifted 4 cm sideways (a few pixels each at 128 x 128). Fitting with the
// avatar frozen must find the truth from the image alone, placement and joints together, and lower the image's
// error. (The per-number Adam that L-BFGS replaced traded placement for joints: from a fit turned 0.05 rad, hips bent
// 0.1 rad, shifted 3 cm and pushed back 5 cm it ended 6.3 cm off with the joints bent 3.4 deg;
// docs/archive/results-history.md, "L-BFGS".)
TEST(TrainPoseFitting, FindsAPerturbedPoseFromTheImageAlone) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 10, 128);
  PerturbedFrame setup = perturbed_test_frame(dataset);
  const int64_t f = setup.frame;
  model::Avatar& avatar = setup.avatar;
  const body::SmplxPose& truth = setup.truth;
  const data::FrameRecord& record = dataset.frames[size_t(f)];
  const data::Dataset fitted = train::fit_poses(dataset, data::Split::kTest, avatar, fit_options(60), nullptr, false);
  const train::PoseError before = train::pose_error(record.pose, truth),
                         after = train::pose_error(fitted.frames[size_t(f)].pose, truth);
  const std::string report = train::to_string(before) + " -> " + train::to_string(after);
  EXPECT_LT(after.translation, 0.1 * before.translation) << report;
  EXPECT_LT(after.root, 0.2 * before.root) << report;
  EXPECT_LT(after.body, before.body) << report;
  const auto image_error = [&](const body::SmplxPose& p) {
    at::NoGradGuard no_grad;
    const model::AvatarOutput out = avatar->forward(p, dataset.replay_time(f));
    const RenderResult r = render(model::to_gaussians(out), at::ones({3}), train::render_camera(record));
    return (r.image - dataset.load(f).image).abs().mean().item<double>();
  };
  const double image_before = image_error(record.pose), image_after = image_error(fitted.frames[size_t(f)].pose);
  EXPECT_LT(image_after, image_before) << "image error before " << image_before << ", after " << image_after;
  EXPECT_TRUE(fitted.frames[size_t(f)].pose.non_finite().empty());
  const int64_t other = dataset.split(data::Split::kTrain)[0];
  EXPECT_TRUE(fitted.frames[size_t(other)].pose.body_pose.equal(dataset.frames[size_t(other)].pose.body_pose))
      << "frames of other splits keep their fits";
}

// From the exact pose the fit has nothing to gain: it must not wander off (a rate-driven optimiser jitters every
// parameter by its rate), and its loss is never above the start's.
TEST(TrainPoseFitting, StaysAtTheExactPoseAndNeverEndsWorseThanItsStart) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 10, 64);
  const int64_t f = dataset.split(data::Split::kTest)[0];
  model::Avatar avatar = render_frames_with_avatar(dataset, {f});
  train::PoseFitter fitter(fit_options(30), at::kCPU, nullptr);
  const body::SmplxPose& truth = dataset.frames[size_t(f)].pose;
  const train::PoseFitTarget target = train::pose_fit_target(dataset, f, at::kCPU, false);
  const train::PoseFitResult exact = fitter.fit(avatar, truth, target, at::zeros({kCorrectionWidth}));
  EXPECT_LE(exact.loss, exact.start_loss);
  const train::PoseError e = train::pose_error(train::corrected_pose(truth, exact.correction), truth);
  EXPECT_LT(e.root, 0.5) << train::to_string(e);
  EXPECT_LT(e.body, 0.5) << train::to_string(e);
  EXPECT_LT(e.translation, 0.5) << train::to_string(e);
  // A start far outside the basin (1 rad, 30 cm): whatever the stages find, the result is no worse than the start.
  at::Tensor far = at::zeros({kCorrectionWidth});
  far[1] = 1.0;
  far[kCorrectionWidth - 3] = 0.3;
  const train::PoseFitResult lost = fitter.fit(avatar, truth, target, far);
  EXPECT_LE(lost.loss, lost.start_loss);
}

// The avatar's keypoints (read from its posed model vertices and joints) land where `sfgs synth` projected the
// body's: one definition, the same body, so an exact fit reprojects onto exact detections and the term is 0.
TEST(TrainPoseFitting, AvatarKeypointsReprojectOntoExactDetections) {
  TempFolder folder;
  const data::Dataset dataset = video_with_exact_keypoints(folder, 4, 96);
  model::AvatarConfig config = small_config();
  config.subdivision_levels = 1;  // the model's vertices are the first of the subdivided mesh's points
  model::Avatar avatar(procedural_avatar_body(), dataset.betas, config);
  const body::WholeBodyKeypointMap map = train::body_keypoint_map("");
  for (int64_t f = 0; f < dataset.size(); ++f) {
    const data::FrameRecord& record = dataset.frames[size_t(f)];
    ASSERT_FALSE(record.keypoints_path.empty()) << "the synthetic video lists its keypoint files";
    const at::Tensor detections = data::read_wholebody_keypoints(record.keypoints_path);
    const Camera camera = train::render_camera(record);
    at::NoGradGuard no_grad;
    const model::AvatarOutput out = avatar->forward(record.pose, dataset.replay_time(f));
    const train::FrameKeypoints keypoints = train::frame_keypoints(detections, camera);
    const at::Tensor points = train::avatar_camera_keypoints(map, avatar, out, keypoints.world_to_camera);
    const at::Tensor pixels =
        points.narrow(1, 0, 2) / points.narrow(1, 2, 1) * at::tensor({camera.fx, camera.fy}, at::kFloat) +
        at::tensor({camera.cx, camera.cy}, at::kFloat);
    const at::Tensor seen = detections.select(1, 2) > 0;
    ASSERT_GT(seen.sum().item<int64_t>(), 100) << "most keypoints lie in the image";
    const at::Tensor error = (pixels - detections.narrow(1, 0, 2)).norm(2, 1).masked_select(seen);
    EXPECT_LT(error.max().item<double>(), 0.05) << "frame " << f << ": pixels (files hold 1/100 px)";
    EXPECT_LT(train::keypoint_reprojection_loss(map, avatar, out, keypoints).item<double>(), 1e-6);
  }
  const Camera camera = train::render_camera(dataset.frames[0]);
  expect_error([&] { train::frame_keypoints(at::zeros({17, 3}), camera); }, {"(133, 3)", "[17, 3]"});
  at::NoGradGuard no_grad;
  const model::AvatarOutput out = avatar->forward(dataset.frames[0].pose, dataset.replay_time(0));
  expect_error([&] { train::keypoint_reprojection_loss(map, avatar, out, train::FrameKeypoints{}); },
               {"no detections"});
}

// From a start far outside the image's basin (turned 0.5 rad, hips bent 0.3 rad, 10 cm sideways and 60 cm back),
// exact detections pull the fit in: within 3 % of the start's translation error and a third of its turn (a turn
// about the vertical hardly moves a frontal body's keypoints). The image alone ended 4.5 and 64 cm off from it (with
// one and two threads: from so far its path depends on the summation order), so that is not asserted.
TEST(TrainPoseFitting, KeypointsPinThePlacementFromAFarStart) {
  TempFolder folder;
  data::Dataset dataset = video_with_exact_keypoints(folder, 10, 128);
  PerturbedFrame setup = perturbed_test_frame(dataset, 0.5f, 0.3f, 0.1f, 0.6f);
  const int64_t f = setup.frame;
  model::Avatar& avatar = setup.avatar;
  const body::SmplxPose& truth = setup.truth;
  const data::FrameRecord& record = dataset.frames[size_t(f)];
  const body::WholeBodyKeypointMap map = train::body_keypoint_map("");
  const data::Dataset fitted = train::fit_poses(dataset, data::Split::kTest, avatar, fit_options(100), &map, false);
  const train::PoseError before = train::pose_error(record.pose, truth),
                         anchored = train::pose_error(fitted.frames[size_t(f)].pose, truth);
  const std::string report = train::to_string(before) + " -> " + train::to_string(anchored);
  EXPECT_LT(anchored.translation, 0.03 * before.translation) << report;
  EXPECT_LT(anchored.root, 0.35 * before.root) << report;
}

// Pose refinement's alignment: at an iteration of align_at every training fit is fitted to its image with the avatar
// as it is (never ending above the start's loss) and the error against the truth logged (error_against_truth); at
// other iterations nothing happens. Passes before align_orientation_from and align_joints_from move the translation
// alone; passes from them on fit the orientation and the joints too.
TEST(TrainPoseRefinement, AlignmentFitsThePlacementThenTheJointsOfTheTrainingFits) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 6, 128);
  const std::vector<int64_t> train_frames = dataset.split(data::Split::kTrain);
  model::Avatar avatar = render_frames_with_avatar(dataset, train_frames);
  for (const int64_t f : train_frames)
    dataset.frames[size_t(f)].pose = perturbed(dataset.frames[size_t(f)].pose, 0.08f, 0.1f, 0.04f, 0.0f);
  train::PoseRefinementConfig config = refinement();
  config.start = 0;
  config.align_at = {0.3, 0.5};
  config.align_joints_from = 0.5;
  config.align_orientation_from = 0.5;
  config.align_iterations = 30;
  train::PoseRefinement r(dataset, config, 10, at::kCPU, nullptr);
  train::LossWeights loss;
  loss.use_lpips = false;
  EXPECT_TRUE(r.align(4, avatar, loss, true).empty()) << "not an alignment iteration";
  const nlohmann::json placement = r.align(3, avatar, loss, true);
  ASSERT_EQ(placement.value("event", ""), "pose_alignment");
  EXPECT_LE(placement.at("loss_after").get<double>(), placement.at("loss_before").get<double>());
  const nlohmann::json& error = placement.at("pose_error");
  EXPECT_EQ(placement.at("pose_error_before").at("refined"), error.at("input")) << "no correction before the pass";
  for (const char* key : {"root_deg", "body_deg", "hands_deg"})  // left to the later passes
    EXPECT_EQ(error.at("refined").at(key), error.at("input").at(key)) << key;
  EXPECT_NE(error.at("refined").at("translation_cm"), error.at("input").at("translation_cm"));
  const nlohmann::json joints = r.align(5, avatar, loss, true);
  ASSERT_EQ(joints.value("event", ""), "pose_alignment");
  EXPECT_LT(joints.at("loss_after").get<double>(), joints.at("loss_before").get<double>());
  EXPECT_EQ(joints.at("pose_error_before"), placement.at("pose_error")) << "the fits as the placement pass left them";
  for (const char* key : {"root_deg", "body_deg"})
    EXPECT_NE(joints.at("pose_error").at("refined").at(key), error.at("input").at(key)) << key << " is fitted too";

  // A pass from align_orientation_from on but before align_joints_from turns the body and leaves its joints; with
  // the turn free the translation comes nearer the truth (held to it, it covered part of the turn).
  config.align_orientation_from = 0.3;
  train::PoseRefinement turning(dataset, config, 10, at::kCPU, nullptr);
  const nlohmann::json turned = turning.align(3, avatar, loss, true).at("pose_error");
  EXPECT_NE(turned.at("refined").at("root_deg"), turned.at("input").at("root_deg"));
  EXPECT_EQ(turned.at("refined").at("body_deg"), turned.at("input").at("body_deg"));
  EXPECT_LT(turned.at("refined").at("translation_cm").get<double>(),
            turned.at("input").at("translation_cm").get<double>());
}

TEST(TrainPoseRefinement, AlignmentSettingsAreChecked) {
  const auto config = [](const std::string& section) {
    return train::TrainConfig::from_yaml_text("pose_refinement:\n" + section).validate();
  };
  config("  enabled: true\n  align_at: [0.2, 0.5]\n  align_iterations: 10\n");
  expect_error([&] { config("  align_at: [0.5, 0.2]\n"); }, {"pose_refinement.align_at", "0.2"});
  expect_error([&] { config("  start: 0.3\n  align_at: [0.1]\n"); }, {"pose_refinement.align_at", "0.1"});
  expect_error([&] { config("  align_at: [1.0]\n"); }, {"pose_refinement.align_at"});
  expect_error([&] { config("  align_iterations: 0\n"); }, {"pose_refinement.align_iterations"});
  config("  smoothing_seconds: 0.1\n");
  expect_error([&] { config("  smoothing_seconds: -0.1\n"); }, {"pose_refinement.smoothing_seconds", "-0.1"});
  expect_error([&] { config("  smoothing_seconds: .nan\n"); }, {"pose_refinement.smoothing_seconds"});
  config("  enabled: false\n  align_at: []\n");
  expect_error([&] { config("  enabled: true\n  align_at: []\n"); },
               {"nothing would move the fits", "pose_refinement.align_at"});
  // The removed per-step corrections: their keys load, a positive rate is refused in a config to train with.
  config("  learning_rate: 0\n  prior: 0.01\n  smoothness: 0.05\n");
  expect_error([&] { config("  translation_learning_rate: 0.005\n"); },
               {"pose_refinement.translation_learning_rate", "per-step pose corrections were removed"});
  expect_error([&] { config("  align_joints_from: 1.5\n"); }, {"pose_refinement.align_joints_from", "1.5"});
  expect_error([&] { config("  align_orientation_from: -0.1\n"); }, {"pose_refinement.align_orientation_from", "-0.1"});
  expect_error([&] { config("  align_orientation_from: 0.6\n  align_joints_from: 0.4\n"); },
               {"pose_refinement.align_orientation_from", "must not exceed", "pose_refinement.align_joints_from"});
}

TEST(TrainPoseRefinement, BadRefinedFitsFilesAreRefused) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 10, 16);
  const auto write = [&](const std::string& name, const nlohmann::json& j) {
    std::ofstream(folder / name) << j.dump();
    return folder / name;
  };
  expect_error(
      [&] {
        train::apply_refined_fits(dataset, write("a.json", {{"format", "other"}}));
      },
      {"a.json", "refined-fits"});
  const std::string frame = dataset.frames[0].name;
  expect_error(
      [&] {
        train::apply_refined_fits(dataset, write("b.json", {{"format", "sfgs-refined-fits"},
                                                            {"frames", {{frame, {{"global_orient", {0, 0, 0}}}}}}}));
      },
      {"b.json", frame, "body_pose"});
}

}  // namespace
}  // namespace sfgs::testing
