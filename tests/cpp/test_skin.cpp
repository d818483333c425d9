// The fused skinning op (csrc/ops/skin/skin.h) against its LibTorch reference composition: forward in float64 and
// float32, gradients (the transforms' too) against the reference's autograd and against central finite differences
// in float64, the sparse weight rows, and the checks of its inputs.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "ops/skin/skin.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

struct Scene {
  at::Tensor dense, transforms, means, log_scales, rest;
};

// n Gaussians influenced by up to 4 of j joints (weights summing to 1, some rows with fewer), random affine
// transforms near the identity.
Scene random_scene(int64_t n, int64_t j, at::ScalarType dtype, uint64_t seed) {
  at::manual_seed(seed);
  const auto options = at::TensorOptions().dtype(dtype);
  at::Tensor raw = at::rand({n, j}, options);
  const at::Tensor kth = std::get<0>(raw.topk(4, 1)).select(1, 3).unsqueeze(1);
  raw = at::where(raw >= kth, raw, at::zeros_like(raw));
  raw.select(0, 0).zero_();
  raw.select(0, 0)[1] = 1;  // a row with one influence
  Scene s;
  s.dense = raw / raw.sum(1, true);
  s.transforms = at::eye(4, options).repeat({j, 1, 1});
  s.transforms.narrow(1, 0, 3).add_(0.3 * at::randn({j, 3, 4}, options));
  s.means = at::randn({n, 3}, options);
  s.log_scales = -2 + 0.5 * at::randn({n}, options);
  s.rest = at::randn({n, 3}, options);
  return s;
}

// A scalar loss of the op's outputs with random weights: its gradient to each output is that output's weights.
struct WeightedLoss {
  at::Tensor means, covariances, posed_rest;
  WeightedLoss(int64_t n, const at::TensorOptions& options)
      : means(at::randn({n, 3}, options)),
        covariances(at::randn({n, 6}, options)),
        posed_rest(at::randn({n, 3}, options)) {}
  at::Tensor operator()(const skin::SkinnedGaussians& out) const {
    at::Tensor loss = (out.means * means).sum() + (out.covariances * covariances).sum();
    return out.posed_rest.defined() ? loss + (out.posed_rest * posed_rest).sum() : loss;
  }
};

TEST(SkinOp, MatchesTheLibTorchReferenceInFloat64AndFloat32) {
  for (const auto dtype : {at::kDouble, at::kFloat}) {
    const Scene s = random_scene(300, 9, dtype, 1);
    const skin::SkinnedGaussians fused =
        skin::skin_gaussians(skin::SkinningWeights::from_dense(s.dense), s.transforms, s.means, s.log_scales, s.rest);
    const skin::SkinnedGaussians reference =
        skin::skinning_reference(s.dense, s.transforms, s.means, s.log_scales, s.rest);
    const double bound = dtype == at::kDouble ? 1e-12 : 1e-5;
    EXPECT_LT(max_difference(fused.means, reference.means), bound) << dtype;
    EXPECT_LT(max_difference(fused.covariances, reference.covariances), bound) << dtype;
    EXPECT_LT(max_difference(fused.posed_rest, reference.posed_rest), bound) << dtype;
  }
}

TEST(SkinOp, GradientsMatchTheReferenceAndFiniteDifferences) {
  const Scene s = random_scene(40, 6, at::kDouble, 2);
  const skin::SkinningWeights weights = skin::SkinningWeights::from_dense(s.dense);
  const WeightedLoss loss_of(40, s.means.options());
  const auto gradients = [&](bool fused) {
    const at::Tensor means = s.means.clone().requires_grad_(true);
    const at::Tensor log_scales = s.log_scales.clone().requires_grad_(true);
    const at::Tensor rest = s.rest.clone().requires_grad_(true);
    const skin::SkinnedGaussians out = fused ? skin::skin_gaussians(weights, s.transforms, means, log_scales, rest)
                                             : skin::skinning_reference(s.dense, s.transforms, means, log_scales, rest);
    return torch::autograd::grad({loss_of(out)}, {means, log_scales, rest});
  };
  const auto fused = gradients(true), reference = gradients(false);
  for (size_t k = 0; k < fused.size(); ++k) EXPECT_LT(max_difference(fused[k], reference[k]), 1e-12) << k;
  const at::Tensor& fused_means = fused[0];
  const at::Tensor& fused_scales = fused[1];

  // Central differences of the fused forward, for a few entries of each input.
  const double h = 1e-6;
  const auto loss_at = [&](const at::Tensor& means, const at::Tensor& log_scales) {
    return loss_of(skin::skin_gaussians(weights, s.transforms, means, log_scales)).item<double>();
  };
  for (int64_t i : {0, 7, 39})
    for (int64_t c = 0; c < 3; ++c) {
      at::Tensor plus = s.means.clone(), minus = s.means.clone();
      plus[i][c] += h;
      minus[i][c] -= h;
      const double numeric = (loss_at(plus, s.log_scales) - loss_at(minus, s.log_scales)) / (2 * h);
      EXPECT_NEAR(fused_means[i][c].item<double>(), numeric, 1e-6 * (1 + std::abs(numeric))) << i << "," << c;
    }
  for (int64_t i : {0, 13, 39}) {
    at::Tensor plus = s.log_scales.clone(), minus = s.log_scales.clone();
    plus[i] += h;
    minus[i] -= h;
    const double numeric = (loss_at(s.means, plus) - loss_at(s.means, minus)) / (2 * h);
    EXPECT_NEAR(fused_scales[i].item<double>(), numeric, 1e-6 * (1 + std::abs(numeric))) << i;
  }
}

// A pose being fitted differentiates the transforms through the fused node: against the reference's autograd, and
// against central differences of the fused forward; the unread last row gets none.
TEST(SkinOp, TransformGradientsMatchTheReferenceAndFiniteDifferences) {
  const Scene s = random_scene(50, 5, at::kDouble, 3);
  const skin::SkinningWeights weights = skin::SkinningWeights::from_dense(s.dense);
  const WeightedLoss loss_of(50, s.means.options());
  for (const bool with_rest : {true, false}) {
    const at::Tensor rest = with_rest ? s.rest : at::Tensor();
    const auto gradients = [&](bool fused) {
      const at::Tensor transforms = s.transforms.clone().requires_grad_(true);
      const at::Tensor means = s.means.clone().requires_grad_(true);
      const skin::SkinnedGaussians out = fused
                                             ? skin::skin_gaussians(weights, transforms, means, s.log_scales, rest)
                                             : skin::skinning_reference(s.dense, transforms, means, s.log_scales, rest);
      return torch::autograd::grad({loss_of(out)}, {transforms, means});
    };
    const auto fused = gradients(true), reference = gradients(false);
    EXPECT_LT(max_difference(fused[0], reference[0]), 1e-11) << "with rest " << with_rest;
    EXPECT_LT(max_difference(fused[1], reference[1]), 1e-12) << "with rest " << with_rest;
    EXPECT_EQ(fused[0].select(1, 3).abs().sum().item<double>(), 0);
    const double h = 1e-6;
    const auto loss_at = [&](const at::Tensor& transforms) {
      return loss_of(skin::skin_gaussians(weights, transforms, s.means, s.log_scales, rest)).item<double>();
    };
    for (int64_t joint : {0, 2, 4})
      for (int64_t row : {0, 2})
        for (int64_t column : {0, 1, 3}) {
          at::Tensor plus = s.transforms.clone(), minus = s.transforms.clone();
          plus[joint][row][column] += h;
          minus[joint][row][column] -= h;
          const double numeric = (loss_at(plus) - loss_at(minus)) / (2 * h);
          EXPECT_NEAR(fused[0][joint][row][column].item<double>(), numeric, 1e-6 * (1 + std::abs(numeric)))
              << joint << "," << row << "," << column << " with rest " << with_rest;
        }
  }
}

// The CPU sums the transforms' gradient in fixed chunks: the same bits on one thread as on several.
TEST(SkinOp, TheTransformGradientIsTheSameForAnyThreadCount) {
  const Scene s = random_scene(9000, 7, at::kFloat, 8);
  const skin::SkinningWeights weights = skin::SkinningWeights::from_dense(s.dense);
  const auto gradient = [&](int threads) {
    const int before = at::get_num_threads();
    at::set_num_threads(threads);
    const at::Tensor transforms = s.transforms.clone().requires_grad_(true);
    const skin::SkinnedGaussians out = skin::skin_gaussians(weights, transforms, s.means, s.log_scales, s.rest);
    const at::Tensor grad =
        torch::autograd::grad({out.means.sum() + out.covariances.sum() + out.posed_rest.sum()}, {transforms})[0];
    at::set_num_threads(before);
    return grad;
  };
  EXPECT_TRUE(at::equal(gradient(1), gradient(2)));
}

TEST(SkinningWeights, KeepEveryNonZeroWeightOfEachRow) {
  const Scene s = random_scene(50, 8, at::kFloat, 4);
  const skin::SkinningWeights weights = skin::SkinningWeights::from_dense(s.dense);
  EXPECT_EQ(weights.weights.size(1), 4);
  EXPECT_EQ(weights.joints.scalar_type(), at::kInt);
  EXPECT_TRUE(weights.to_dense().equal(s.dense));
}

TEST(SkinOp, RefusesBadInputsWithClearErrors) {
  const Scene s = random_scene(10, 4, at::kFloat, 5);
  const skin::SkinningWeights weights = skin::SkinningWeights::from_dense(s.dense);
  const auto message = [&](const std::function<void()>& call) {
    try {
      call();
    } catch (const c10::Error& e) {
      return std::string(e.what_without_backtrace());
    }
    return std::string("no error");
  };
  EXPECT_NE(message([&] {
              skin::skin_gaussians(weights, s.transforms.narrow(0, 0, 3), s.means, s.log_scales);
            }).find("transforms must have shape (4, 4, 4)"),
            std::string::npos);
  EXPECT_NE(message([&] {
              skin::skin_gaussians(weights, s.transforms, s.means.narrow(0, 0, 9), s.log_scales);
            }).find("canonical_means must have shape (10, 3)"),
            std::string::npos);
  EXPECT_NE(message([&] {
              skin::skin_gaussians(weights, s.transforms, s.means.to(at::kDouble), s.log_scales);
            }).find("canonical_means must be Float"),
            std::string::npos);
  EXPECT_NE(message([&] { skin::SkinningWeights::from_dense(at::ones({3})); }).find("floating (N, J)"),
            std::string::npos);
}

// The op through the dispatcher, as torch.ops.sfgs.skin_gaussians is called: its kernels, a Meta kernel that describes
// the outputs, and the backward op.
std::vector<c10::IValue> op_arguments(const Scene& s, bool with_rest) {
  const skin::SkinningWeights w = skin::SkinningWeights::from_dense(s.dense);
  const int64_t j = s.transforms.size(0);
  return {s.means,  s.log_scales, with_rest ? c10::IValue(s.rest) : c10::IValue(),
          w.joints, w.weights,    s.transforms.narrow(1, 0, 3).reshape({j, 12}).contiguous()};
}

TEST(SkinOp, IsADispatcherOpWhoseMetaKernelsDescribeItsOutputs) {
  expect_backend_kernels("sfgs::skin_gaussians", true);
  expect_backend_kernels("sfgs::skin_gaussians_backward", false);
  const Scene s = random_scene(40, 6, at::kFloat, 6);
  for (const bool with_rest : {true, false}) {
    expect_meta_describes_cpu("sfgs::skin_gaussians", op_arguments(s, with_rest));
    const std::vector<c10::IValue> forward = op_arguments(s, with_rest);
    const at::Tensor covariances = call_boxed(registered_op("sfgs::skin_gaussians"), forward)[1].toTensor();
    const c10::IValue none;
    const c10::IValue grad_rest = with_rest ? c10::IValue(at::randn({40, 3})) : none;
    expect_meta_describes_cpu("sfgs::skin_gaussians_backward", {forward[3], forward[4], forward[5], covariances,
                                                                at::randn({40, 3}), none, grad_rest, none, none, none});
    // With the forward's inputs: the transform rows' gradient too.
    expect_meta_describes_cpu("sfgs::skin_gaussians_backward",
                              {forward[3], forward[4], forward[5], covariances, at::randn({40, 3}), at::randn({40, 6}),
                               grad_rest, forward[0], forward[1], forward[2]});
  }
}

TEST(SkinOp, TheDispatcherCallIsTheFunctionAndAJointOutOfRangeGivesNan) {
  const Scene s = random_scene(30, 5, at::kDouble, 7);
  std::vector<c10::IValue> arguments = op_arguments(s, true);
  const std::vector<c10::IValue> out = call_boxed(registered_op("sfgs::skin_gaussians"), arguments);
  const skin::SkinnedGaussians direct =
      skin::skin_gaussians(skin::SkinningWeights::from_dense(s.dense), s.transforms, s.means, s.log_scales, s.rest);
  EXPECT_TRUE(at::equal(out[0].toTensor(), direct.means));
  EXPECT_TRUE(at::equal(out[1].toTensor(), direct.covariances));
  EXPECT_TRUE(at::equal(out[2].toTensor(), direct.posed_rest));
  at::Tensor joints = arguments[3].toTensor().clone();
  joints[2][0] = 5;  // one past the last joint (its weight is non-zero: every row's first pick is its largest)
  arguments[3] = joints;
  const at::Tensor means = call_boxed(registered_op("sfgs::skin_gaussians"), arguments)[0].toTensor();
  EXPECT_TRUE(means[2].isnan().all().item<bool>());
  EXPECT_TRUE(at::equal(means.narrow(0, 3, 27), direct.means.narrow(0, 3, 27)));
  arguments[1] = s.log_scales.narrow(0, 0, 29);
  EXPECT_THROW(call_boxed(registered_op("sfgs::skin_gaussians"), arguments), c10::Error);
}

}  // namespace
}  // namespace sfgs::testing
