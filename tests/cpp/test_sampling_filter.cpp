// The sampling filter (csrc/model/sampling_filter.h): a pixel's footprint at each Gaussian, the record an avatar keeps,
// the variance a finer render adds (exactly, and nothing at the training's sampling), and the Animator with a record:
// unchanged at the training's sampling, covered where a render twice as fine leaves holes.
#include <cmath>
#include <limits>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "animate/animator.h"
#include "ops/splat/constants.h"
#include "model/sampling_filter.h"
#include "test_avatar_utils.h"
#include "test_body_utils.h"

namespace sfgs::testing {
namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();

// A camera 3 m in front of the body (+z), looking back at it with y up in the image, the whole body in view; `scale`
// times the pixels.
Camera whole_body_camera(int64_t scale = 1) {
  Camera c = Camera::looking_forward(30.0 * double(scale), 48 * scale, 64 * scale);
  c.world_to_camera = {1, 0, 0, 0, 0, -1, 0, 0.3, 0, 0, -1, 3, 0, 0, 0, 1};
  return c;
}

TEST(SamplingFilter, AFootprintIsDepthOverFocalInViewAndInfiniteElsewhere) {
  Camera c = Camera::looking_forward(100, 40, 30);
  c.fy = 400;                                                            // f = sqrt(100 * 400) = 200
  c.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 1, 0, 0, 0, 1};  // the world 1 m in front
  // In view at depth 2; beside the image; behind the camera; NaN.
  const at::Tensor means = at::tensor({0.0, 0.0, 1.0, 5.0, 0.0, 1.0, 0.0, 0.0, -2.0, NAN, 0.0, 1.0}).view({4, 3});
  const at::Tensor f = model::frame_footprint(means, c);
  EXPECT_NEAR(f[0].item<double>(), 2.0 / 200.0, 1e-9);
  for (int64_t k = 1; k < 4; ++k) EXPECT_EQ(f[k].item<double>(), kInfinity) << k;
}

TEST(SamplingFilter, TheRecordGivesGaussiansNoViewHeldTheMedianAndRefusesNaN) {
  const at::Tensor r = model::sampling_record(at::tensor({0.01, kInfinity, 0.03, 0.02}));
  EXPECT_TRUE(r.equal(at::tensor({0.01f, 0.02f, 0.03f, 0.02f})));
  EXPECT_TRUE(model::sampling_record(at::full({3}, kInfinity)).equal(at::zeros({3}))) << "none held: no filter";
  expect_error([] { model::sampling_record(at::tensor({0.01, NAN})); }, {"sampling record", "NaN"});
  expect_error([] { model::sampling_record(at::tensor({0.01, -1.0})); }, {"non-negative"});
}

TEST(SamplingFilter, AFinerRenderAddsTheMissingLowPassOnTheDiagonalOnly) {
  const Camera c = Camera::looking_forward(100, 40, 30);
  at::manual_seed(3);
  const at::Tensor covariances = at::rand({3, 6}, at::kDouble);
  const at::Tensor means = at::tensor({0.0, 0.0, 1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 4.0}, at::kDouble).view({3, 3});
  // Footprints 0.01, 0.02, 0.04 against a record of 0.02 each: only the first is seen more finely.
  const at::Tensor record = at::full({3}, 0.02, at::kDouble);
  const at::Tensor filtered = model::sampling_filtered(covariances, means, c, record);
  const double added = kLowPassVariancePx2 * (0.02 * 0.02 - 0.01 * 0.01);
  const at::Tensor expected_first = covariances[0] + added * at::tensor({1.0, 0.0, 0.0, 1.0, 0.0, 1.0}, at::kDouble);
  EXPECT_LT((filtered[0] - expected_first).abs().max().item<double>(), 1e-15);
  EXPECT_TRUE(filtered.slice(0, 1).equal(covariances.slice(0, 1))) << "at or coarser than the training's: unchanged";
  // The added world variance, seen by this camera, is the low-pass the training's pixels had less this one's.
  EXPECT_NEAR(added * 100 * 100 / (1.0 * 1.0), kLowPassVariancePx2 * (4 - 1), 1e-9);
  // The same depths through a placed camera: the means 0.5 m lower in z, the camera's translation 0.5 m.
  Camera placed = c;
  placed.world_to_camera[11] = 0.5;
  const at::Tensor moved = means - at::tensor({0.0, 0.0, 0.5}, at::kDouble);
  EXPECT_LT((model::sampling_filtered(covariances, moved, placed, record) - filtered).abs().max().item<double>(),
            1e-15);
}

TEST(SamplingFilter, AnAvatarRefusesABadRecordByName) {
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  const int64_t n = avatar->gaussian_count();
  expect_error([&] { avatar->set_sampling_record(at::ones({n + 1})); }, {"sampling record", std::to_string(n)});
  expect_error([&] { avatar->set_sampling_record(at::full({n}, -1.0)); }, {"sampling record", "non-negative"});
  expect_error([&] { avatar->set_sampling_record(at::full({n}, kInfinity)); }, {"sampling record", "finite"});
  avatar->set_sampling_record(at::full({n}, 0.01));
  EXPECT_TRUE(avatar->sampling_record().defined());
  avatar->set_sampling_record(at::Tensor());
  EXPECT_FALSE(avatar->sampling_record().defined()) << "undefined clears it";
}

model::Avatar small_gaussian_avatar() {
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 31);
  // Gaussians far smaller than the spacing of the points: the dotted surface of an avatar seen more finely than it was
  // trained, here already at the training's sampling (the low-pass fills the gaps).
  at::NoGradGuard no_grad;
  for (auto& p : avatar->named_parameters()) {
    // The geometry head's output layer (mean offset, log-scale offset): no offsets, every scale e^-2.5 of its start.
    if (p.key().find("heads.geometry") == std::string::npos || p.value().size(0) != 4) continue;
    p.value().zero_();
    if (p.value().dim() == 1) p.value()[3] = -2.5;
  }
  return avatar;
}

TEST(SamplingFilter, TheAnimatorIsUnchangedAtTheTrainingsSamplingAndCoveredAtTwiceIt) {
  model::Avatar avatar = small_gaussian_avatar();
  const body::SmplxPose pose = test_pose(5, 0.2, true);
  const at::Tensor background = at::ones({3});
  at::Tensor record;
  {
    at::NoGradGuard no_grad;
    avatar->eval();
    record =
        model::sampling_record(model::frame_footprint(avatar->forward(pose, std::nullopt).means, whole_body_camera()));
  }
  const auto render = [&](const at::Tensor& r, int64_t scale) {
    avatar->set_sampling_record(r);
    animate::Animator animator(avatar, whole_body_camera(scale), background);
    animator.render(pose);
    return std::pair{animator.latest().image.clone(), animator.latest().alpha.clone()};
  };
  const auto [plain, plain_alpha] = render(at::Tensor(), 1);
  const auto [filtered, filtered_alpha] = render(record, 1);
  // Left alone up to the rounding of the depths (the record's and the Animator's come through different placements).
  EXPECT_LT((filtered - plain).abs().max().item<double>(), 1e-5) << "the training's own view";

  // Twice the pixels: the person as the 1x render covers it, upsampled.
  const at::Tensor person = (plain_alpha >= 0.5).repeat_interleave(2, 0).repeat_interleave(2, 1);
  const auto uncovered = [&](const at::Tensor& alpha) {
    return (person & (alpha < 0.95)).sum().item<double>() / person.sum().item<double>();
  };
  const double without = uncovered(render(at::Tensor(), 2).second), with = uncovered(render(record, 2).second);
  EXPECT_GT(without, 0.02) << "a render twice as fine falls apart without the filter";
  EXPECT_LT(with, 0.5 * without) << "without " << without << ", with " << with;
  EXPECT_LE(with, uncovered((plain_alpha.repeat_interleave(2, 0).repeat_interleave(2, 1))) + 0.01)
      << "about as covered as the training's own view";
}

}  // namespace
}  // namespace sfgs::testing
