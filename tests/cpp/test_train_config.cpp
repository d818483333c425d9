// Training configuration, schedule and loss pieces that need no trained avatar.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "test_files.h"
#include "ops/pixel_loss/pixel_loss.h"
#include "train/losses.h"
#include "train/train_config.h"
#include "train/trainer.h"

namespace sfgs::train {
namespace {

TEST(TrainConfig, YamlRoundTripAndOverrides) {
  const TrainConfig c = TrainConfig::from_yaml_text(
      "avatar:\n  use_hexplane: false\n  plane_resolution: 64\nschedule:\n  iterations: 200\nloss:\n  "
      "mean_offset_parts: {body: 2, face: 3, hands: 4}\n");
  EXPECT_FALSE(c.avatar.use_hexplane);
  EXPECT_EQ(c.avatar.plane_resolution, 64);
  EXPECT_EQ(c.schedule.iterations, 200);
  EXPECT_EQ(c.loss.mean_offset_parts.hands, 4);
  EXPECT_EQ(c.loss.lpips_every, 1) << "LPIPS in every step unless configured";
  EXPECT_TRUE(c.loss.lpips_bfloat16);
  EXPECT_TRUE(c.schedule.tf32_matmul);
  EXPECT_TRUE(c.schedule.cuda_graphs);
  EXPECT_EQ(c.loss.image, 0.8) << "defaults are the paper's best setting";
  const TrainConfig back = TrainConfig::from_yaml_text(c.to_yaml());
  EXPECT_EQ(back.to_yaml(), c.to_yaml());
}

TEST(TrainConfig, MistakesAreClearErrors) {
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("avatar:\n  use_hexplan: false\n"); },
                                   "unknown key 'avatar.use_hexplan'");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("optimiser: {}\n"); },
                                   "unknown section 'optimiser'");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("schedule:\n  iterations: many\n"); },
                                   "bad value for 'schedule.iterations'");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("schedule:\n  iterations: 0\n"); },
                                   "schedule.iterations must be an integer in [1, 100000000], got 0");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_file("/nonexistent/config.yaml"); },
                                   "/nonexistent/config.yaml");
  // A key or a section given twice would let the last silently win.
  testing::expect_error_mentioning(
      [] { TrainConfig::from_yaml_text("schedule:\n  iterations: 10\n  iterations: 20\n"); },
      "'schedule.iterations' is given twice (again on line 3)");
  testing::expect_error_mentioning(
      [] { TrainConfig::from_yaml_text("schedule:\n  iterations: 10\nloss: {}\nschedule:\n  iterations: 20\n"); },
      "'schedule' is given twice (again on line 4)");
}

// The adversarial values that used to train to "final loss -nan" with exit 0: each is refused naming the key.
TEST(TrainConfig, NonFiniteAndOutOfRangeValuesAreRefused) {
  const auto refused = [](const std::string& yaml, const std::string& message) {
    testing::expect_error_mentioning([&] { TrainConfig::from_yaml_text(yaml, "bad.yaml"); }, message);
  };
  refused("schedule: {learning_rate: .inf}\n",
          "config 'bad.yaml': schedule.learning_rate must be a finite number in (0, 1], got inf");
  refused("schedule: {learning_rate: 1e30}\n", "schedule.learning_rate must be a finite number in (0, 1], got 1e+30");
  refused("schedule: {colour_learning_rate: -0.001}\n", "schedule.colour_learning_rate must be a finite number");
  refused("schedule: {adam_epsilon: .nan}\n", "schedule.adam_epsilon must be a finite number in (0, 1], got nan");
  refused("schedule: {decay_factor: [0.1, .inf]}\n", "schedule.decay_factor must be a finite number in (0, 1]");
  refused("schedule: {decay_at: [0.5, .nan]}\n", "schedule.decay_at must rise strictly inside (0, 1)");
  refused("loss: {image: .nan}\n", "loss.image must be a finite number in [0, 1e+09], got nan");
  refused("loss: {laplacian_mean: 1e30}\n", "loss.laplacian_mean must be a finite number in [0, 1e+09]");
  refused("loss: {lab: -1}\n", "loss.lab must be a finite number in [0, 1e+09], got -1");
  refused("loss: {scale_parts: {hands: .inf}}\n", "loss.scale_parts.hands must be a finite number");
  refused("avatar: {plane_resolution: 1000000}\n", "avatar.plane_resolution must be an integer in [2, 4096]");
  refused("run: {validation_frames: 0}\n", "run.validation_frames must be an integer in [1, 100000000], got 0");
  refused("loss: {lpips_every: 0}\n", "loss.lpips_every must be an integer in [1, 100000000], got 0");
  // The defaults and the shipped configs are inside every range.
  EXPECT_NO_THROW(TrainConfig{}.validate());
}

TEST(TrainConfig, ChangesAreListedAndOnlyScheduleAndLoggingMayChangeOnResume) {
  TrainConfig a, b;
  b.schedule.iterations = a.schedule.iterations + 10;
  b.avatar.hidden_width = 64;
  b.loss.lab = 0.5;
  const std::vector<ConfigChange> changes = config_changes(a, b);
  ASSERT_EQ(changes.size(), 3u);
  EXPECT_EQ(changes[0].key, "avatar.hidden_width");
  EXPECT_EQ(changes[0].before, "128");
  EXPECT_EQ(changes[0].after, "64");
  EXPECT_EQ(changes[1].key, "loss.lab");
  EXPECT_EQ(changes[2].key, "schedule.iterations");
  EXPECT_TRUE(change_allowed_on_resume("schedule.iterations"));
  EXPECT_TRUE(change_allowed_on_resume("run.log_every"));
  EXPECT_TRUE(change_allowed_on_resume("run.device"));
  EXPECT_FALSE(change_allowed_on_resume("avatar.hidden_width"));
  EXPECT_FALSE(change_allowed_on_resume("loss.lab"));
  EXPECT_FALSE(change_allowed_on_resume("run.seed"));
  EXPECT_FALSE(change_allowed_on_resume("body.smplx"));
  EXPECT_TRUE(config_changes(a, a).empty());
}

// A run's stored config lists every key of its time: a key it lacks came later, and takes the value that reproduces
// what the run did (no alignment passes, placement-only passes that turn the body, no keypoint term), so resuming an
// older run does not change its objective; a config a user writes takes today's defaults. A run of a version with
// per-step pose corrections (removed since) still loads: its rates are ignored with a warning.
TEST(TrainConfig, KeysAStoredConfigLacksKeepTheBehaviourOfItsTime) {
  const std::string before_joint_passes =
      "pose_refinement: {enabled: true, align_at: [0.1, 0.6], keypoint_weight: 1}\n";
  const TrainConfig stored = TrainConfig::from_stored_yaml_text(before_joint_passes, "stored");
  EXPECT_EQ(stored.pose_refinement.align_at, (std::vector<double>{0.1, 0.6}));
  EXPECT_EQ(stored.pose_refinement.align_joints_from, 1.0) << "its pass at 0.6 stays placement-only";
  EXPECT_EQ(stored.pose_refinement.align_orientation_from, 0.0) << "and still turns the body";
  EXPECT_EQ(stored.pose_refinement.keypoint_weight, 1.0);
  const TrainConfig oldest = TrainConfig::from_stored_yaml_text(
      "pose_refinement: {enabled: true, learning_rate: 0.01, translation_learning_rate: 0.005}\n", "stored");
  EXPECT_TRUE(oldest.pose_refinement.enabled);
  EXPECT_TRUE(oldest.pose_refinement.align_at.empty()) << "its fits moved with per-step corrections alone";
  EXPECT_EQ(oldest.pose_refinement.keypoint_weight, 0.0);
  EXPECT_THROW(TrainConfig::from_yaml_text("pose_refinement: {enabled: true, learning_rate: 0.01}\n"), c10::Error)
      << "a config to train with may not ask for them";
  const TrainConfig written = TrainConfig::from_yaml_text("pose_refinement: {enabled: true}\n");
  EXPECT_EQ(written.pose_refinement.align_at, TrainConfig{}.pose_refinement.align_at);
  EXPECT_EQ(written.pose_refinement.align_joints_from, TrainConfig{}.pose_refinement.align_joints_from);
  EXPECT_EQ(written.pose_refinement.align_orientation_from, TrainConfig{}.pose_refinement.align_orientation_from);
  EXPECT_EQ(written.pose_refinement.keypoint_weight, TrainConfig{}.pose_refinement.keypoint_weight);
  // A stored config written today round-trips to itself.
  const TrainConfig today = TrainConfig::from_stored_yaml_text(TrainConfig{}.to_yaml(), "stored");
  EXPECT_TRUE(config_changes(TrainConfig{}, today).empty());
}

TEST(TrainSchedule, WarmUpThenStepDecay) {
  Schedule s;
  s.iterations = 1000;
  s.warmup_iterations = 10;
  EXPECT_DOUBLE_EQ(learning_rate_factor(s, 0), 0.1);
  EXPECT_DOUBLE_EQ(learning_rate_factor(s, 9), 1.0);
  EXPECT_DOUBLE_EQ(learning_rate_factor(s, 749), 1.0);
  EXPECT_DOUBLE_EQ(learning_rate_factor(s, 750), 0.1);
  EXPECT_DOUBLE_EQ(learning_rate_factor(s, 950), 0.01);
}

TEST(TrainLosses, LabOfKnownColours) {
  const at::Tensor lab =
      pixel_loss::rgb_to_lab(at::tensor({1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0}, at::kDouble).view({3, 3}));
  EXPECT_NEAR(lab[0][0].item<double>(), 1.0, 1e-4);  // white: L = 100
  EXPECT_NEAR(lab[0][1].item<double>(), 0.0, 1e-4);
  EXPECT_NEAR(lab[1][0].item<double>(), 0.0, 1e-9);          // black: L = 0
  EXPECT_NEAR(lab[2][0].item<double>(), 53.24 / 100, 1e-3);  // sRGB red: L 53.24, a 80.09, b 67.20
  EXPECT_NEAR(lab[2][1].item<double>(), 80.09 / 110, 2e-3);
  EXPECT_NEAR(lab[2][2].item<double>(), 67.20 / 110, 2e-3);
  at::Tensor x = at::full({2, 3}, 0.0, at::kDouble).requires_grad_(true);
  pixel_loss::rgb_to_lab(x).sum().backward();
  EXPECT_TRUE(x.grad().isfinite().all().item<bool>()) << "finite gradient at black";
}

}  // namespace
}  // namespace sfgs::train

namespace sfgs::train {
namespace {

// loss.lpips_every: a step without LPIPS leaves it out of the image term (and reports no "lpips"), the rest equal.
TEST(TrainImageLoss, StepsWithoutLpipsLeaveItOut) {
  const ImageLoss loss(LossWeights{}, at::kCPU);
  if (loss.lpips_status().find("skipped") != std::string::npos) GTEST_SKIP() << loss.lpips_status();
  at::Generator g = at::detail::createCPUGenerator(4);
  const at::Tensor prediction = at::rand({64, 64, 3}, g), target = at::rand({64, 64, 3}, g);
  LossTerms with, without;
  loss.add_terms(prediction, target, with, true);
  loss.add_terms(prediction, target, without, false);
  ASSERT_TRUE(with.count("lpips"));
  EXPECT_FALSE(without.count("lpips"));
  EXPECT_NEAR((with["image"] - without["image"]).item<double>(), LossWeights{}.image * with["lpips"].item<double>(),
              1e-6);
  for (const char* same : {"l1", "ssim", "lab", "gradient"})
    EXPECT_EQ(with[same].item<double>(), without[same].item<double>()) << same;
}

}  // namespace
}  // namespace sfgs::train
