// Gradients of the CPU splatting op: central finite differences in float64, the independent brute-force reference
// (forward values and its autograd gradients), and float32 against float64.
#include <string>

#include <ATen/core/grad_mode.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "splat_test_utils.h"

namespace sfgs::testing {
namespace {

struct GradientCase {
  std::string name;
  bool covariances;
  bool low_pass;
  bool antialiased;
  int64_t channels;
};

std::ostream& operator<<(std::ostream& os, const GradientCase& c) { return os << c.name; }

class SplatGradients : public ::testing::TestWithParam<GradientCase> {
 protected:
  RenderOptions options() const {
    RenderOptions o;
    o.low_pass = GetParam().low_pass;
    o.antialiased = GetParam().antialiased;
    return o;
  }
  TestScene scene(uint64_t seed) const {
    SceneSpec spec;
    spec.covariances = GetParam().covariances;
    spec.channels = GetParam().channels;
    return smooth_random_scene(spec, seed, options());
  }
};

TEST_P(SplatGradients, ForwardEqualsBruteForceReference) {
  for (uint64_t seed : {1u, 2u, 3u}) {
    TestScene s = scene(seed);
    const RenderResult r = render(s.gaussians, s.background, s.camera, options());
    const ReferenceImage ref = reference_render(s.gaussians, s.background, s.camera, options());
    EXPECT_LE((r.image - ref.image).abs().max().item<double>(), 1e-12) << "seed " << seed;
    EXPECT_LE((r.alpha - ref.alpha).abs().max().item<double>(), 1e-12) << "seed " << seed;
    EXPECT_LE((r.depth - ref.depth).abs().max().item<double>(), 1e-10) << "seed " << seed;
    EXPECT_GT(r.alpha.max().item<double>(), 0.3) << "the scene must actually cover pixels";
  }
}

TEST_P(SplatGradients, GradientsEqualReferenceAutograd) {
  TestScene s = scene(11);
  const LossWeights w = random_weights(s.camera.height, s.camera.width, GetParam().channels, 5, at::kDouble);
  auto inputs = differentiable_inputs(s);
  std::vector<at::Tensor> leaves;
  for (auto& [name, t] : inputs) leaves.push_back(t->set_requires_grad(true));
  const RenderResult r = render(s.gaussians, s.background, s.camera, options());
  const auto ours = torch::autograd::grad({weighted_loss(r.image, r.alpha, r.depth, w)}, leaves);
  const ReferenceImage ref = reference_render(s.gaussians, s.background, s.camera, options());
  const auto theirs = torch::autograd::grad({weighted_loss(ref.image, ref.alpha, ref.depth, w)}, leaves);
  for (size_t i = 0; i < leaves.size(); ++i) EXPECT_LE(relative_error(ours[i], theirs[i]), 1e-9) << inputs[i].first;
}

TEST_P(SplatGradients, GradientsEqualFiniteDifferences) {
  TestScene s = scene(21);
  const LossWeights w = random_weights(s.camera.height, s.camera.width, GetParam().channels, 9, at::kDouble);
  auto inputs = differentiable_inputs(s);
  std::vector<at::Tensor> leaves;
  for (auto& [name, t] : inputs) leaves.push_back(t->set_requires_grad(true));
  const RenderResult r = render(s.gaussians, s.background, s.camera, options());
  const auto analytic = torch::autograd::grad({weighted_loss(r.image, r.alpha, r.depth, w)}, leaves);
  const auto loss = [&] {
    at::NoGradGuard no_grad;
    const RenderResult q = render(s.gaussians, s.background, s.camera, options());
    return weighted_loss(q.image, q.alpha, q.depth, w).item<double>();
  };
  for (size_t i = 0; i < leaves.size(); ++i) {
    const at::Tensor numeric = finite_difference(loss, leaves[i], 1e-6);
    EXPECT_GT(analytic[i].abs().max().item<double>(), 0.0) << inputs[i].first << " received no gradient";
    EXPECT_LE(relative_error(analytic[i], numeric), 1e-6) << inputs[i].first;
  }
}

TEST_P(SplatGradients, Float32AgreesWithFloat64) {
  TestScene s64 = scene(31);
  TestScene s32 = s64;
  for (auto& [name, t] : differentiable_inputs(s32)) *t = t->to(at::kFloat);
  const LossWeights w64 = random_weights(s64.camera.height, s64.camera.width, GetParam().channels, 3, at::kDouble);
  const LossWeights w32{w64.image.to(at::kFloat), w64.alpha.to(at::kFloat), w64.depth.to(at::kFloat)};
  auto run = [&](TestScene& s, const LossWeights& w) {
    auto inputs = differentiable_inputs(s);
    std::vector<at::Tensor> leaves;
    for (auto& [name, t] : inputs) leaves.push_back(t->set_requires_grad(true));
    const RenderResult r = render(s.gaussians, s.background, s.camera, options());
    auto grads = torch::autograd::grad({weighted_loss(r.image, r.alpha, r.depth, w)}, leaves);
    grads.insert(grads.begin(), r.image.detach());
    return grads;
  };
  const auto g64 = run(s64, w64);
  const auto g32 = run(s32, w32);
  // float32 rounding (2^-24 ~ 6e-8 per operation) through ~10 blended layers and the 1/z^2, 1/det chains of the
  // projection keeps images within 1e-5 and gradients within 1e-4 (relative L2).
  EXPECT_LE((g32[0].to(at::kDouble) - g64[0]).abs().max().item<double>(), 1e-5);
  const auto names = differentiable_inputs(s64);
  for (size_t i = 1; i < g64.size(); ++i) EXPECT_LE(relative_error(g32[i], g64[i]), 1e-4) << names[i - 1].first;
}

INSTANTIATE_TEST_SUITE_P(Cases, SplatGradients,
                         ::testing::Values(GradientCase{"scales_rotations", false, true, false, 3},
                                           GradientCase{"covariances", true, true, false, 3},
                                           GradientCase{"antialiased", false, true, true, 3},
                                           GradientCase{"no_low_pass", false, false, false, 3},
                                           GradientCase{"one_channel", false, true, false, 1},
                                           GradientCase{"five_channels_covariances_antialiased", true, true, true, 5}),
                         [](const ::testing::TestParamInfo<GradientCase>& info) { return info.param.name; });

}  // namespace
}  // namespace sfgs::testing
