// The animation path on the GPU: the skinning kernel against the CPU reference (forward and gradients, float64 and
// float32), the splatting op under a binning budget (within it: the plain render exactly; beyond it: only the
// background, with the true counts reported), and the Animator's CUDA graph frames against eager frames, including
// a frame that outgrows its budget and a new pose layout. SkinCudaSanitizer.* and AnimatorCuda.GraphFrame* run under
// compute-sanitizer in scripts/device_check.sh. Every test skips without a CUDA device.
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "animate/animator.h"
#include "skin/skin.h"
#include "test_avatar_utils.h"

namespace sfgs::testing {
namespace {

#define SKIP_WITHOUT_CUDA() \
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device"

double max_difference(const at::Tensor& a, const at::Tensor& b) {
  return (a.cpu() - b.cpu()).abs().max().item<double>();
}

void expect_skinning_parity(at::ScalarType dtype, int64_t n, double bound) {
  at::manual_seed(7);
  const auto cpu = at::TensorOptions().dtype(dtype);
  const int64_t j = 55;
  at::Tensor raw = at::rand({n, j}, cpu);
  raw = at::where(raw > 0.93, raw, at::zeros_like(raw)) + at::one_hot(at::randint(j, {n}), j).to(dtype);
  const at::Tensor dense = raw / raw.sum(1, true);
  at::Tensor transforms = at::eye(4, cpu).repeat({j, 1, 1});
  transforms.narrow(1, 0, 3).add_(0.3 * at::randn({j, 3, 4}, cpu));
  const at::Tensor means = at::randn({n, 3}, cpu), log_scales = -2 + 0.3 * at::randn({n}, cpu);
  const at::Tensor rest = at::randn({n, 3}, cpu);
  const at::Tensor grad_means = at::randn({n, 3}, cpu), grad_covariances = at::randn({n, 6}, cpu);
  const skin::SkinningWeights weights = skin::SkinningWeights::from_dense(dense);

  const auto run = [&](at::Device device) {
    const at::Tensor m = means.to(device).requires_grad_(true), s = log_scales.to(device).requires_grad_(true);
    const skin::SkinnedGaussians out =
        skin::skin_gaussians(weights.to(device, dtype), transforms.to(device), m, s, rest.to(device));
    const at::Tensor loss = (out.means * grad_means.to(device)).sum() +
                            (out.covariances * grad_covariances.to(device)).sum();
    const auto g = torch::autograd::grad({loss}, {m, s});
    return std::vector<at::Tensor>{out.means, out.covariances, out.posed_rest, g[0], g[1]};
  };
  const std::vector<at::Tensor> on_cpu = run(at::kCPU), on_gpu = run(at::kCUDA);
  const char* names[] = {"means", "covariances", "posed rest", "mean gradient", "log-scale gradient"};
  for (size_t k = 0; k < on_cpu.size(); ++k)
    EXPECT_LT(max_difference(on_cpu[k], on_gpu[k]) / (1 + on_cpu[k].abs().max().item<double>()), bound)
        << names[k] << " " << dtype;
}

TEST(SkinCudaSanitizer, MatchesTheCpuReferenceInFloat64) {
  SKIP_WITHOUT_CUDA();
  expect_skinning_parity(at::kDouble, 5000, 1e-12);
}

TEST(SkinCuda, MatchesTheCpuReferenceInFloat32AtAvatarScale) {
  SKIP_WITHOUT_CUDA();
  expect_skinning_parity(at::kFloat, 200000, 1e-5);
}

// A camera 3 m in front of the body (+z), looking back at it with y up in the image.
Camera front_camera(int64_t width, int64_t height) {
  Camera c = Camera::looking_forward(1.2 * double(height), width, height);
  c.world_to_camera = {1, 0, 0, 0, 0, -1, 0, 0.3, 0, 0, -1, 3, 0, 0, 0, 1};
  return c;
}

model::Avatar cuda_avatar() {
  model::AvatarConfig config = small_config();
  config.subdivision_levels = 1;
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), config);
  randomise_parameters(*avatar, 0.1, 31);
  avatar->to(at::kCUDA);
  return avatar;
}

TEST(BinningBudget, WithinItTheRenderIsThePlainOneAndBeyondItOnlyTheBackground) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  avatar->eval();
  at::NoGradGuard no_grad;
  const Gaussians g = model::to_gaussians(avatar->forward(test_pose(1, 0.3, true), std::nullopt));
  const at::Tensor background = at::tensor({0.2f, 0.4f, 0.6f}).cuda();
  const Camera camera = front_camera(96, 128);
  const at::Tensor plain = render(g, background, camera).image;
  const at::Tensor counts = at::zeros({BinningBudget::kCounts}, at::TensorOptions(at::kCUDA).dtype(at::kLong));
  at::Tensor within;
  {
    const ScopedBinningBudget budget(BinningBudget{1 << 22, 1 << 22, counts});
    within = render(g, background, camera).image;
  }
  EXPECT_TRUE(within.equal(plain));
  const at::Tensor reported = counts.cpu();
  const int64_t intersections = reported[0].item<int64_t>();
  EXPECT_GT(intersections, 0);
  EXPECT_GT(reported[1].item<int64_t>(), 0);
  EXPECT_EQ(reported[2].item<int64_t>(), 0);
  {
    // A budget that fits exactly: the per-tile sort when the longest tile allows it (else the radix path again).
    const ScopedBinningBudget budget(BinningBudget{intersections, reported[1].item<int64_t>(), counts});
    EXPECT_TRUE(render(g, background, camera).image.equal(plain));
  }

  at::Tensor beyond;
  {
    const ScopedBinningBudget budget(BinningBudget{intersections - 1, 1 << 22, counts});
    beyond = render(g, background, camera).image;
  }
  EXPECT_TRUE(beyond.equal(background.view({1, 1, 3}).expand_as(beyond)));
  EXPECT_EQ(counts.cpu()[0].item<int64_t>(), intersections);
}

TEST(AnimatorCuda, GraphFramesEqualEagerFramesOverAMotion) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  animate::AnimatorOptions eager_options;
  eager_options.use_graph = false;
  animate::Animator eager(avatar, front_camera(96, 128), background, eager_options);
  animate::Animator graphed(avatar, front_camera(96, 128), background);
  for (int64_t k = 0; k < 6; ++k) {
    const body::SmplxPose pose = test_pose(10 + k, 0.1 + 0.1 * double(k), true);
    const at::Tensor from_graph = graphed.render(pose).clone();
    EXPECT_LT(max_difference(from_graph, eager.render(pose)), 1e-6) << "frame " << k;
  }
  EXPECT_EQ(graphed.stats().graph_frames, 6);
  EXPECT_GE(graphed.stats().captures, 1);
}

TEST(AnimatorCuda, GraphFrameThatOutgrowsItsBudgetIsRenderedAgainWhole) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  // No headroom: the budget is exactly the first frame's count. That frame is one 16 x 16 tile, so every Gaussian
  // in view touches exactly one tile; the same view at 384 x 512 has the same Gaussians in view and those on a tile
  // border touch several: the budget is exceeded, grown, and the frame recorded and replayed again.
  animate::AnimatorOptions tight;
  tight.budget_slack = 1.0;
  const Camera one_tile = front_camera(16, 16), close = front_camera(384, 512);
  animate::Animator graphed(avatar, one_tile, background, tight);
  graphed.render(test_pose(20, 0.05, true));
  animate::AnimatorOptions eager_options;
  eager_options.use_graph = false;
  animate::Animator eager(avatar, close, background, eager_options);
  graphed.set_camera(close);
  const body::SmplxPose pose = test_pose(21, 0.05, true);
  const at::Tensor from_graph = graphed.render(pose).clone();
  EXPECT_LT(max_difference(from_graph, eager.render(pose)), 1e-6);
  EXPECT_GE(graphed.stats().budget_overflows, 1) << "intersections " << graphed.stats().intersections << ", budget "
                                                 << graphed.stats().budget;
}

TEST(AnimatorCuda, GraphFrameOfANewPoseLayoutCapturesAgain) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  animate::Animator graphed(avatar, front_camera(96, 128), background);
  animate::AnimatorOptions eager_options;
  eager_options.use_graph = false;
  animate::Animator eager(avatar, front_camera(96, 128), background, eager_options);
  const body::SmplxPose with_hands = test_pose(30, 0.2, true), without_hands = test_pose(31, 0.2, false);
  graphed.render(with_hands);
  const int64_t captures = graphed.stats().captures;
  const at::Tensor from_graph = graphed.render(without_hands).clone();
  EXPECT_LT(max_difference(from_graph, eager.render(without_hands)), 1e-6);
  EXPECT_EQ(graphed.stats().captures, captures + 1);
}

}  // namespace
}  // namespace sfgs::testing
