// Noisy fits on purpose (data/pose_noise.h): the errors have the documented sizes and split into jitter and drift,
// depth errors lie along the camera's axis, hands are swapped at the documented rate, the zero level changes
// nothing, and the corruption is a function of its seed.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <cmath>

#include "body/rotations.h"
#include "body/skeleton.h"
#include "data/motions.h"
#include "data/pose_noise.h"
#include "test_files.h"

namespace sfgs::data {
namespace {

constexpr double kFps = 30.0;
constexpr double kDegree = M_PI / 180.0;

// `frames` frames of the walk at 30 fps (a moving truth, so the errors are measured on real rotations).
body::SmplxPose walk(int64_t frames) {
  std::vector<body::SmplxPose> poses;
  for (int64_t i = 0; i < frames; ++i) poses.push_back(motion_pose("walk", double(i) / kFps, 10));
  return body::SmplxPose::stack(poses);
}

at::Tensor times(int64_t frames) { return at::arange(frames, at::kDouble) / kFps; }

at::Tensor identity_cameras(int64_t frames) { return at::eye(3, at::kDouble).expand({frames, 3, 3}).contiguous(); }

// Angle (radians) of the rotation between two axis-angle tensors (..., 3).
at::Tensor angle_between(const at::Tensor& a, const at::Tensor& b) {
  const at::Tensor ra = body::axis_angle_to_matrix(a.to(at::kDouble)),
                   rb = body::axis_angle_to_matrix(b.to(at::kDouble));
  return body::matrix_to_axis_angle(ra.matmul(rb.transpose(-1, -2))).norm(2, -1);
}

double rms(const at::Tensor& t) { return t.square().mean().sqrt().item<double>(); }

TEST(PoseNoise, ZeroLevelLeavesTheFitsExact) {
  const body::SmplxPose truth = walk(20);
  const at::Tensor betas = at::linspace(-1, 1, 10);
  const NoisyFits n = corrupt_fits(truth, betas, times(20), identity_cameras(20), pose_noise_level("none"), 7);
  for (const auto& f : body::SmplxPose::fields())
    EXPECT_TRUE(at::equal(n.poses.*(f.member), truth.*(f.member))) << f.name;
  EXPECT_TRUE(at::equal(n.betas, betas));
  EXPECT_FALSE(n.hands_swapped.any().item<bool>());
}

TEST(PoseNoise, ErrorsHaveTheLevelsSizes) {
  const int64_t frames = 6000;  // 200 s: some 200 independent stretches of the 1 s drift
  const body::SmplxPose truth = walk(frames);
  PoseNoiseLevel level = pose_noise_level("medium,swap=0");
  const NoisyFits n = corrupt_fits(truth, at::zeros({10}), times(frames), identity_cameras(frames), level, 3);
  const at::Tensor body = angle_between(n.poses.body_pose, truth.body_pose);  // (B, 21)
  const at::Tensor wrists = at::stack(
      {body.select(1, body::smplx_joint::kLeftWrist - 1), body.select(1, body::smplx_joint::kRightWrist - 1)}, 1);
  const at::Tensor others = at::cat({body.narrow(1, 0, body::smplx_joint::kLeftWrist - 1)}, 1);
  EXPECT_NEAR(rms(others), level.body_degrees * kDegree, 0.08 * level.body_degrees * kDegree);
  EXPECT_NEAR(rms(wrists), level.hand_degrees * kDegree, 0.1 * level.hand_degrees * kDegree);
  const at::Tensor fingers = angle_between(n.poses.left_hand_pose, truth.left_hand_pose);
  EXPECT_NEAR(rms(fingers), level.hand_degrees * kDegree, 0.08 * level.hand_degrees * kDegree);
  EXPECT_NEAR(rms(angle_between(n.poses.global_orient, truth.global_orient)), level.root_degrees * kDegree,
              0.12 * level.root_degrees * kDegree);
  const at::Tensor shift = n.poses.transl - truth.transl;  // identity cameras: x, y across the view, z along it
  EXPECT_NEAR(rms(shift.narrow(1, 0, 2)), level.lateral_cm / 100, 0.12 * level.lateral_cm / 100);
  EXPECT_NEAR(rms(shift.select(1, 2)), level.depth_cm / 100, 0.12 * level.depth_cm / 100);
  EXPECT_TRUE(at::equal(n.poses.expression, truth.expression)) << "expressions are left exact";
}

TEST(PoseNoise, ErrorsSplitIntoJitterAndSlowDrift) {
  const int64_t frames = 6000;
  const body::SmplxPose truth = walk(frames);
  const PoseNoiseLevel level = pose_noise_level("medium");
  const NoisyFits n = corrupt_fits(truth, at::zeros({10}), times(frames), identity_cameras(frames), level, 5);
  const at::Tensor error = (n.poses.transl - truth.transl).select(1, 2).to(at::kDouble);
  // Consecutive differences: 2 sigma^2 (jitter share + drift share (1 - exp(-dt / drift))).
  const double rho = std::exp(-1.0 / kFps / level.drift_seconds);
  const double expected = 2 * (level.jitter_share + (1 - level.jitter_share) * (1 - rho));
  const double measured =
      (error.narrow(0, 1, frames - 1) - error.narrow(0, 0, frames - 1)).square().mean().item<double>() /
      error.square().mean().item<double>();
  EXPECT_NEAR(measured, expected, 0.1 * expected);
}

TEST(PoseNoise, DepthErrorsLieAlongEachCamerasAxis) {
  const int64_t frames = 4000;
  const body::SmplxPose truth = walk(frames);
  // A camera turned 90 degrees about y looks along the world's x axis.
  const at::Tensor turn = body::axis_angle_to_matrix(at::tensor({0.0, M_PI / 2, 0.0}, at::kDouble));
  const at::Tensor cameras = turn.expand({frames, 3, 3}).contiguous();
  const PoseNoiseLevel level = pose_noise_level("high,swap=0");
  const NoisyFits n = corrupt_fits(truth, at::zeros({10}), times(frames), cameras, level, 11);
  const at::Tensor in_camera = (n.poses.transl - truth.transl).to(at::kDouble).matmul(turn.t());
  EXPECT_NEAR(rms(in_camera.select(1, 2)), level.depth_cm / 100, 0.12 * level.depth_cm / 100);
  EXPECT_NEAR(rms(in_camera.select(1, 0)), level.lateral_cm / 100, 0.12 * level.lateral_cm / 100);
}

TEST(PoseNoise, HandsAreSwappedAtTheDocumentedRateAsMirrorImages) {
  const int64_t frames = 5000;
  const body::SmplxPose truth = walk(frames);
  PoseNoiseLevel level;  // nothing but swaps, so a swapped hand is exactly the other hand mirrored
  level.hand_swap_rate = 0.1;
  const NoisyFits n = corrupt_fits(truth, at::zeros({10}), times(frames), identity_cameras(frames), level, 13);
  const double rate = n.hands_swapped.to(at::kDouble).mean().item<double>();
  EXPECT_NEAR(rate, 0.1, 4 * std::sqrt(0.1 * 0.9 / frames));
  const at::Tensor swapped = n.hands_swapped.nonzero().squeeze(1);
  ASSERT_GT(swapped.size(0), 0);
  EXPECT_TRUE(at::allclose(n.poses.left_hand_pose.index_select(0, swapped),
                           mirror_axis_angle(truth.right_hand_pose.index_select(0, swapped)), 1e-5, 1e-5));
  const at::Tensor kept = (~n.hands_swapped).nonzero().squeeze(1);
  EXPECT_TRUE(at::allclose(n.poses.right_hand_pose.index_select(0, kept), truth.right_hand_pose.index_select(0, kept),
                           1e-5, 1e-5));
}

TEST(PoseNoise, IsAFunctionOfItsSeed) {
  const body::SmplxPose truth = walk(50);
  const PoseNoiseLevel level = pose_noise_level("high");
  const auto run = [&](uint64_t seed) {
    return corrupt_fits(truth, at::zeros({10}), times(50), identity_cameras(50), level, seed);
  };
  const NoisyFits a = run(21), b = run(21), c = run(22);
  for (const auto& f : body::SmplxPose::fields())
    EXPECT_TRUE(at::equal(a.poses.*(f.member), b.poses.*(f.member))) << f.name;
  EXPECT_TRUE(at::equal(a.betas, b.betas));
  EXPECT_FALSE(at::equal(a.poses.body_pose, c.poses.body_pose));
}

TEST(PoseNoise, LevelsParseWithOverridesAndBadOnesAreClearErrors) {
  const PoseNoiseLevel low = pose_noise_level("low"), medium = pose_noise_level("default");
  EXPECT_EQ(medium.name, "medium");
  EXPECT_DOUBLE_EQ(low.body_degrees * 2, medium.body_degrees);
  EXPECT_DOUBLE_EQ(pose_noise_level("high").depth_cm, 2 * medium.depth_cm);
  EXPECT_TRUE(pose_noise_level("none").is_zero());
  const PoseNoiseLevel custom = pose_noise_level("low,hands=15,depth=10,swap=0.05");
  EXPECT_DOUBLE_EQ(custom.hand_degrees, 15);
  EXPECT_DOUBLE_EQ(custom.depth_cm, 10);
  EXPECT_DOUBLE_EQ(custom.hand_swap_rate, 0.05);
  EXPECT_DOUBLE_EQ(custom.body_degrees, low.body_degrees);
  testing::expect_error_mentioning([] { pose_noise_level("extreme"); }, "none, low, medium");
  testing::expect_error_mentioning([] { pose_noise_level("medium,elbows=3"); }, "'elbows=3' is not key=value");
  testing::expect_error_mentioning([] { pose_noise_level("medium,swap=2"); }, "swap=2 must be a number in [0, 1]");
  testing::expect_error_mentioning([] { pose_noise_level("medium,depth=abc"); }, "depth=abc");
}

}  // namespace
}  // namespace sfgs::data
