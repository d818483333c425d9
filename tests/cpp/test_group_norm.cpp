// The fused GroupNorm + ReLU op (ops/group_norm/group_norm.h) on the CPU backend: against torch.nn.GroupNorm with its
// affine map and a ReLU (forward and every gradient, float64), against central differences, its LibTorch reference,
// float32 against float64, a group of equal values, and the errors at its boundary.
#include <algorithm>
#include <functional>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "model/constants.h"
#include "ops/group_norm/group_norm.h"
#include "model/mlp.h"
#include "test_files.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using group_norm::group_norm_relu;
using group_norm::group_norm_relu_reference;

struct Inputs {
  at::Tensor pre, bias, gamma, beta;
  std::vector<at::Tensor> differentiable() const {
    std::vector<at::Tensor> v{pre, gamma, beta};
    if (bias.defined()) v.push_back(bias);
    return v;
  }
};

Inputs random_inputs(int64_t rows, int64_t channels, bool with_bias, uint64_t seed) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  Inputs in;
  in.pre = at::randn({rows, channels}, g, kF64).requires_grad_(true);
  if (with_bias) in.bias = at::randn({channels}, g, kF64).requires_grad_(true);
  in.gamma = (1 + 0.5 * at::randn({channels}, g, kF64)).requires_grad_(true);
  in.beta = (0.3 * at::randn({channels}, g, kF64)).requires_grad_(true);
  return in;
}

// What the op computes, as torch.nn.GroupNorm with its affine map and a ReLU.
at::Tensor torch_composition(const Inputs& in, int64_t groups) {
  const at::Tensor h = in.bias.defined() ? in.pre + in.bias : in.pre;
  return at::relu(at::group_norm(h, groups, in.gamma, in.beta, kMlpGroupNormEpsilon));
}

TEST(GroupNormRelu, MatchesTorchGroupNormWithGradients) {
  struct Case {
    int64_t rows, channels, groups;
    bool bias;
  };
  // 3,000 rows span three of the CPU backend's partial rows of column sums.
  for (const Case c : {Case{3000, 128, 4, true}, Case{7, 12, 3, false}, Case{50, 64, 1, true}, Case{1, 8, 8, true}}) {
    const Inputs in = random_inputs(c.rows, c.channels, c.bias, 7);
    const at::Tensor weights = at::randn({c.rows, c.channels}, kF64);
    const at::Tensor expected = torch_composition(in, c.groups);
    const auto expected_grads = torch::autograd::grad({(expected * weights).sum()}, in.differentiable());
    for (const bool fused : {true, false}) {
      const std::string what = std::string(fused ? "op" : "reference") + " at " + std::to_string(c.rows) + " x " +
                               std::to_string(c.channels) + " in " + std::to_string(c.groups);
      const at::Tensor got =
          fused ? group_norm_relu(in.pre, in.bias, in.gamma, in.beta, c.groups, kMlpGroupNormEpsilon)
                : group_norm_relu_reference(in.pre, in.bias, in.gamma, in.beta, c.groups, kMlpGroupNormEpsilon);
      EXPECT_LT(max_difference(got, expected), 1e-12) << what;
      const auto grads = torch::autograd::grad({(got * weights).sum()}, in.differentiable());
      for (size_t k = 0; k < grads.size(); ++k)
        EXPECT_LT(max_difference(grads[k], expected_grads[k]), 1e-10) << what << ", input " << k;
    }
  }
}

// The backward's formulas against central differences of the forward alone.
TEST(GroupNormRelu, GradientsMatchCentralDifferences) {
  const Inputs in = random_inputs(5, 8, true, 11);
  const at::Tensor weights = at::randn({5, 8}, kF64);
  const auto objective = [&](const Inputs& x) {
    return (group_norm_relu(x.pre, x.bias, x.gamma, x.beta, 2, kMlpGroupNormEpsilon) * weights).sum();
  };
  const auto analytic = torch::autograd::grad({objective(in)}, in.differentiable());
  const std::vector<at::Tensor> inputs = in.differentiable();
  constexpr double kStep = 1e-6;
  at::NoGradGuard no_grad;
  for (size_t k = 0; k < inputs.size(); ++k) {
    at::Tensor flat = inputs[k].detach().view({-1});
    for (int64_t i = 0; i < flat.numel(); ++i) {
      const double kept = flat[i].item<double>();
      flat[i] = kept + kStep;
      const double up = objective(in).item<double>();
      flat[i] = kept - kStep;
      const double down = objective(in).item<double>();
      flat[i] = kept;
      EXPECT_NEAR(analytic[k].view({-1})[i].item<double>(), (up - down) / (2 * kStep), 1e-6)
          << "input " << k << ", element " << i;
    }
  }
}

TEST(GroupNormRelu, Float32FollowsFloat64) {
  const Inputs in = random_inputs(2000, 128, true, 5);
  const auto as_float = [](const at::Tensor& t) { return t.detach().to(at::kFloat).requires_grad_(true); };
  const Inputs f{as_float(in.pre), as_float(in.bias), as_float(in.gamma), as_float(in.beta)};
  const at::Tensor weights = at::randn({2000, 128}, kF64);
  const at::Tensor expected = group_norm_relu(in.pre, in.bias, in.gamma, in.beta, 4, kMlpGroupNormEpsilon);
  const at::Tensor got = group_norm_relu(f.pre, f.bias, f.gamma, f.beta, 4, kMlpGroupNormEpsilon);
  EXPECT_LT(max_difference(got.to(at::kDouble), expected), 1e-5);
  const auto expected_grads = torch::autograd::grad({(expected * weights).sum()}, in.differentiable());
  const auto grads = torch::autograd::grad({(got * weights.to(at::kFloat)).sum()}, f.differentiable());
  for (size_t k = 0; k < grads.size(); ++k) {
    const double scale = expected_grads[k].abs().max().item<double>();
    EXPECT_LT(max_difference(grads[k].to(at::kDouble), expected_grads[k]), 1e-5 * std::max(1.0, scale)) << k;
  }
}

// A group of equal values has no spread: it normalises to 0 (beta's ReLU) with finite gradients, not NaN.
TEST(GroupNormRelu, ConstantGroupStaysFinite) {
  Inputs in = random_inputs(3, 8, false, 2);
  {
    at::NoGradGuard no_grad;
    in.pre.narrow(1, 0, 4).fill_(2.5);
  }
  const at::Tensor out = group_norm_relu(in.pre, in.bias, in.gamma, in.beta, 2, kMlpGroupNormEpsilon);
  EXPECT_LT(max_difference(out.narrow(1, 0, 4), at::relu(in.beta.narrow(0, 0, 4)).expand({3, 4})), 1e-12);
  for (const at::Tensor& g : torch::autograd::grad({out.sum()}, in.differentiable()))
    EXPECT_TRUE(g.isfinite().all().item<bool>());
}

TEST(GroupNormRelu, RejectsBadInputs) {
  const Inputs in = random_inputs(4, 8, true, 1);
  expect_error_mentioning([&] { group_norm_relu(in.pre.to(at::kInt), in.bias, in.gamma, in.beta, 2, 1e-5); },
                          "float32 or float64");
  expect_error_mentioning([&] { group_norm_relu(in.pre, in.bias, in.gamma, in.beta, 3, 1e-5); },
                          "split into the 3 groups");
  expect_error_mentioning([&] { group_norm_relu(in.pre, in.bias.narrow(0, 0, 4), in.gamma, in.beta, 2, 1e-5); },
                          "bias must be");
  expect_error_mentioning([&] { group_norm_relu(in.pre, in.bias, in.gamma.to(at::kFloat), in.beta, 2, 1e-5); },
                          "gamma must be");
  expect_error_mentioning(
      [&] {
        group_norm_relu(in.pre, in.bias, in.gamma, in.beta.view({2, 4}), 2, 1e-5);
      },
      "beta must be");
  expect_error_mentioning([&] { group_norm_relu(in.pre, in.bias, in.gamma, in.beta, 2, 0.0); },
                          "epsilon must be positive");
  expect_error_mentioning([&] { group_norm_relu(in.pre.view({-1}), in.bias, in.gamma, in.beta, 2, 1e-5); }, "(N, C)");
}

// The layer with its linear map (the product recomputed in the backward) against torch's linear and GroupNorm.
TEST(GroupNormRelu, LinearLayerMatchesTorchWithGradients) {
  at::Generator g = at::detail::createCPUGenerator(21);
  const at::Tensor x = at::randn({2500, 24}, g, kF64).requires_grad_(true);
  const at::Tensor weight = (0.3 * at::randn({64, 24}, g, kF64)).requires_grad_(true);
  const Inputs layer = random_inputs(0, 64, true, 22);  // bias, gamma and beta of the layer
  const at::Tensor weights = at::randn({2500, 64}, g, kF64);
  const std::vector<at::Tensor> inputs{x, weight, layer.bias, layer.gamma, layer.beta};
  const at::Tensor expected =
      at::relu(at::group_norm(at::linear(x, weight, layer.bias), 4, layer.gamma, layer.beta, kMlpGroupNormEpsilon));
  const at::Tensor got =
      group_norm::linear_group_norm_relu(x, weight, layer.bias, layer.gamma, layer.beta, 4, kMlpGroupNormEpsilon);
  EXPECT_LT(max_difference(got, expected), 1e-12);
  const auto expected_grads = torch::autograd::grad({(expected * weights).sum()}, inputs);
  const auto grads = torch::autograd::grad({(got * weights).sum()}, inputs);
  for (size_t k = 0; k < grads.size(); ++k) EXPECT_LT(max_difference(grads[k], expected_grads[k]), 1e-10) << k;
  try {
    group_norm::linear_group_norm_relu(x, weight.narrow(1, 0, 20), layer.bias, layer.gamma, layer.beta, 4, 1e-5);
    ADD_FAILURE() << "a weight of the wrong shape was taken";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what()).find("weight must be a Double (C, 24)"), std::string::npos) << e.what();
  }
}

// The MLP applies it with each hidden layer's bias before its ReLU: the authors' head, composed of torch's layers.
TEST(GroupNormRelu, MlpHiddenLayersAreLinearGroupNormRelu) {
  at::Generator generator = at::detail::createCPUGenerator(12);
  model::Mlp mlp(model::MlpShape{{5, 3}, {16, 16}, 2, /*group_norm=*/true});
  mlp->to(at::kDouble);
  {
    at::NoGradGuard no_grad;
    for (auto& p : mlp->parameters()) p.normal_(0.0, 0.5, generator);
  }
  const auto p = mlp->named_parameters();
  const at::Tensor a = at::randn({64, 5}, generator, kF64), b = at::randn({64, 3}, generator, kF64);
  const at::Tensor first =
      at::linear(at::cat({a, b}, 1), at::cat({p["input0_weight"], p["input1_weight"]}, 1), p["input_bias"]);
  const auto layer = [&](const at::Tensor& x, int k) {
    return at::relu(at::group_norm(x, kMlpGroupNormGroups, p["norm" + std::to_string(k) + "_weight"],
                                   p["norm" + std::to_string(k) + "_bias"], kMlpGroupNormEpsilon));
  };
  const at::Tensor hidden = layer(at::linear(layer(first, 0), p["hidden1_weight"], p["hidden1_bias"]), 1);
  const at::Tensor expected = at::linear(hidden, p["output_weight"], p["output_bias"]);
  const at::Tensor got = mlp->forward({a, b});
  EXPECT_LT(max_difference(got, expected), 1e-12);
  // The first layer's bias is added by the first GroupNorm op (Mlp::bias_in_activation), not by project(0): the
  // projections' sum, finished, is the same function, and every parameter's gradient is the composition's.
  EXPECT_TRUE(mlp->bias_in_activation());
  EXPECT_LT(max_difference(mlp->finish(mlp->project(0, a) + mlp->project(1, b)), expected), 1e-12);
  EXPECT_LT(max_difference(mlp->finish(mlp->project_add(1, b, mlp->project(0, a))), expected), 1e-12);
  const at::Tensor weights = at::randn(expected.sizes(), generator, kF64);
  const std::vector<at::Tensor> parameters = mlp->parameters();
  const auto expected_grads = torch::autograd::grad({(expected * weights).sum()}, parameters);
  const auto grads = torch::autograd::grad({(got * weights).sum()}, parameters);
  for (size_t k = 0; k < grads.size(); ++k) {
    EXPECT_GT(expected_grads[k].abs().max().item<double>(), 0.0) << k;
    EXPECT_LT(max_difference(grads[k], expected_grads[k]), 1e-10) << k;
  }
}

// A network without GroupNorm keeps the bias in project(0) (the gathered MLP and the inference caches bake it).
TEST(GroupNormRelu, PlainMlpKeepsTheFirstBiasInTheProjection) {
  model::Mlp mlp(model::MlpShape{{5}, {16}, 2});
  mlp->to(at::kDouble);
  EXPECT_FALSE(mlp->bias_in_activation());
  const at::Tensor a = at::randn({8, 5}, kF64);
  const auto p = mlp->named_parameters();
  EXPECT_LT(max_difference(mlp->project(0, a), at::linear(a, p["input0_weight"], p["input_bias"])), 1e-12);
  const at::Tensor base = at::randn({8, 16}, kF64);
  EXPECT_LT(max_difference(mlp->project_add(0, a, base), base + mlp->project(0, a)), 1e-12);
  // A base of another shape is refused, not broadcast; so is a first activation of another width.
  const auto refused = [](const std::function<void()>& call, const std::string& part) {
    try {
      call();
      ADD_FAILURE() << "accepted: " << part;
    } catch (const c10::Error& e) {
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
    }
  };
  refused([&] { mlp->project_add(0, a, base.narrow(0, 0, 1)); }, "Mlp::project_add: base must be a Double (8, 16)");
  refused([&] { mlp->finish_activated(base.narrow(1, 0, 15)); },
          "Mlp::finish_activated: the first activation must have shape (N, 16)");
}

TEST(GroupNormRelu, TheOpsAreDispatcherOpsWhoseMetaKernelsDescribeTheirOutputs) {
  expect_backend_kernels("sfgs::group_norm_relu", true);
  expect_backend_kernels("sfgs::linear_group_norm_relu", true);
  expect_backend_kernels("sfgs::group_norm_relu_backward", false);
  for (const bool with_bias : {true, false}) {
    const at::NoGradGuard no_grad;
    const Inputs in = random_inputs(12, 8, with_bias, 4);
    const c10::IValue bias = with_bias ? c10::IValue(in.bias) : c10::IValue();
    expect_meta_describes_cpu("sfgs::group_norm_relu", {in.pre, bias, in.gamma, in.beta, int64_t(2), 1e-5});
    const c10::IValue layer_bias = with_bias ? c10::IValue(in.bias.narrow(0, 0, 6)) : c10::IValue();
    expect_meta_describes_cpu("sfgs::linear_group_norm_relu",
                              {in.pre, at::randn({6, 8}, kF64), layer_bias, in.gamma.narrow(0, 0, 6),
                               in.beta.narrow(0, 0, 6), int64_t(3), 1e-5});
    const std::vector<c10::IValue> forward =
        call_boxed(registered_op("sfgs::group_norm_relu"), {in.pre, bias, in.gamma, in.beta, int64_t(2), 1e-5});
    EXPECT_TRUE(at::equal(forward[0].toTensor(), group_norm_relu(in.pre, in.bias, in.gamma, in.beta, 2, 1e-5)));
    expect_meta_describes_cpu("sfgs::group_norm_relu_backward",
                              {at::randn({12, 8}, kF64), in.pre, bias, in.gamma, in.beta, forward[1], forward[2]});
  }
  const Inputs in = random_inputs(12, 8, true, 5);
  EXPECT_THROW(
      call_boxed(registered_op("sfgs::group_norm_relu"), {in.pre, in.bias, in.gamma, in.beta, int64_t(3), 1e-5}),
      c10::Error);
}

}  // namespace
}  // namespace sfgs::testing
