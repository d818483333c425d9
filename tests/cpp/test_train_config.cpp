// Training configuration, schedule and loss pieces that need no trained avatar.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "test_files.h"
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
  EXPECT_EQ(c.loss.image, 0.8) << "defaults are the paper's best setting";
  const TrainConfig back = TrainConfig::from_yaml_text(c.to_yaml());
  EXPECT_EQ(back.to_yaml(), c.to_yaml());
}

TEST(TrainConfig, MistakesAreClearErrors) {
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("avatar:\n  use_hexplan: false\n"); },
                                   "unknown key 'avatar.use_hexplan'");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("optimiser: {}\n"); }, "unknown section 'optimiser'");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("schedule:\n  iterations: many\n"); },
                                   "bad value for 'schedule.iterations'");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_text("schedule:\n  iterations: 0\n"); },
                                   "schedule.iterations must be at least 1");
  testing::expect_error_mentioning([] { TrainConfig::from_yaml_file("/nonexistent/config.yaml"); },
                                   "/nonexistent/config.yaml");
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
  const at::Tensor lab = rgb_to_lab(at::tensor({1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0}, at::kDouble).view({3, 3}));
  EXPECT_NEAR(lab[0][0].item<double>(), 1.0, 1e-4);   // white: L = 100
  EXPECT_NEAR(lab[0][1].item<double>(), 0.0, 1e-4);
  EXPECT_NEAR(lab[1][0].item<double>(), 0.0, 1e-9);   // black: L = 0
  EXPECT_NEAR(lab[2][0].item<double>(), 53.24 / 100, 1e-3);  // sRGB red: L 53.24, a 80.09, b 67.20
  EXPECT_NEAR(lab[2][1].item<double>(), 80.09 / 110, 2e-3);
  EXPECT_NEAR(lab[2][2].item<double>(), 67.20 / 110, 2e-3);
  at::Tensor x = at::full({2, 3}, 0.0, at::kDouble).requires_grad_(true);
  rgb_to_lab(x).sum().backward();
  EXPECT_TRUE(x.grad().isfinite().all().item<bool>()) << "finite gradient at black";
}

}  // namespace
}  // namespace sfgs::train
