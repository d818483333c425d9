// The gathered MLP (csrc/ops/gathered_mlp/gathered_mlp.h) on the CPU, where it is its LibTorch reference: the same
// function as the structure offset's network on the concatenated inputs, the structure offset's inference path equal
// to its training path, and clear errors at its boundary. The fused CUDA kernel is compared with this reference in
// tests/cuda/test_animate_cuda.cpp. The first layer as a training op (gathered_first_layer) on the CPU backend: its
// value and both gradients against the LibTorch composition and central differences in float64, float32 against
// float64, the backward's determinism, the Mlp's finish from the first activation, the structure offset's gradients,
// and the errors at its boundary; its CUDA kernels are compared with this backend in
// tests/cuda/test_gathered_first_layer_cuda.cpp.
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/csrc/autograd/grad_mode.h>

#include <array>
#include <cmath>
#include <string>
#include <vector>

#include "ops/gathered_mlp/gathered_mlp.h"
#include "model/mlp.h"
#include "model/structure_offset.h"
#include "test_files.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

// Every parameter of `module` replaced by N(0, std^2) noise (the output layers start at zero).
void randomise(torch::nn::Module& module, double std, uint64_t seed) {
  at::NoGradGuard no_grad;
  at::Generator generator = at::detail::createCPUGenerator(seed);
  for (auto& p : module.parameters()) p.copy_(at::normal(0, std, p.sizes(), generator));
}

TEST(GatheredMlp, IsTheNetworkOnTheConcatenatedInputs) {
  const int64_t n = 37, h = 16, rows_width = 5, groups_width = 3, groups = 4;
  model::Mlp mlp(model::MlpShape{{rows_width, groups_width}, {h, h}, 4, false, true});
  randomise(*mlp, 0.5, 3);
  const at::Tensor row_features = at::randn({n, rows_width}), group_features = at::randn({groups, groups_width});
  const at::Tensor ids = at::randint(groups, {n}, at::kLong);
  at::NoGradGuard no_grad;
  const at::Tensor gathered = gathered_mlp::gathered_mlp(mlp->project(0, row_features), mlp->project(1, group_features),
                                                         ids.to(at::kInt), mlp->gathered_weights());
  const at::Tensor whole = mlp->forward({row_features, group_features.index_select(0, ids)});
  EXPECT_TRUE(at::allclose(gathered, whole, 1e-5, 1e-6)) << (gathered - whole).abs().max();
  EXPECT_GT(whole.abs().max().item<double>(), 0.1) << "the network is not the constant zero";
}

TEST(GatheredMlp, StructureOffsetInferenceEqualsItsTrainingPath) {
  const int64_t joints = 55, n = 300, width = 12, hidden = 16;
  const at::Tensor canonical_joints = at::randn({joints, 3}), dominant = at::randint(joints, {n}, at::kLong);
  model::StructureOffset offset(width, hidden, 4, canonical_joints, dominant);
  randomise(*offset, 0.3, 5);
  const at::Tensor projection = offset->project_features(at::randn({n, width})), rotations = at::randn({joints, 6});
  at::NoGradGuard no_grad;
  const model::StructureOffsetOutput training = offset->forward(projection, rotations);
  const model::StructureOffsetOutput inference = offset->forward_inference(projection, rotations);
  EXPECT_TRUE(at::allclose(training.mean_offset, inference.mean_offset, 1e-5, 1e-6));
  EXPECT_TRUE(at::allclose(training.log_scale_offset, inference.log_scale_offset, 1e-5, 1e-6));
}

TEST(GatheredMlp, RefusesBadInputsByName) {
  const int64_t n = 8, h = 4, groups = 3;
  gathered_mlp::GatheredMlpWeights w{at::randn({h, h}), at::randn({h}), at::randn({2, h}), at::randn({2})};
  const at::Tensor rows = at::randn({n, h}), group_rows = at::randn({groups, h});
  const at::Tensor ids = at::randint(groups, {n}, at::kInt);
  at::NoGradGuard no_grad;
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows.narrow(1, 0, 3), group_rows, ids, w); },
                          "hidden_weight must be a floating (3, 3) tensor");
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids.narrow(0, 0, 5), w); },
                          "groups must be an int32 or int64 (8) tensor");
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids.to(at::kFloat), w); },
                          "groups must be an int32 or int64");
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids + groups, w); },
                          "groups must lie in [0, 3)");
  gathered_mlp::GatheredMlpWeights doubles = w;
  doubles.output_bias = w.output_bias.to(at::kDouble);
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids, doubles); },
                          "output_bias must be a Float tensor of shape [2]");
  at::GradMode::set_enabled(true);
  const at::Tensor learned = rows.clone().requires_grad_(true);
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(learned, group_rows, ids, w); }, "inference only");
  at::GradMode::set_enabled(false);
  EXPECT_FALSE(gathered_mlp::fuses(rows, w)) << "CPU tensors take the reference";
}

// Every pre-activation is moved this far from ReLU's kink, so that no central difference crosses it.
constexpr double kKinkMargin = 0.1;

struct FirstLayerInputs {
  at::Tensor rows, group_rows, groups, weights;  // weights: the output's in the loss sum(out * weights)
};

// float64 inputs of n rows of width h in g groups, of which only the first `used_groups` have rows.
FirstLayerInputs first_layer_inputs(int64_t n, int64_t h, int64_t g, int64_t used_groups, uint64_t seed) {
  at::Generator generator = at::detail::createCPUGenerator(seed);
  const at::Tensor group_rows = at::randn({g, h}, generator, kF64);
  const at::Tensor groups = at::randint(used_groups, {n}, generator, at::TensorOptions().dtype(at::kLong));
  const at::Tensor rows = at::randn({n, h}, generator, kF64);
  const at::Tensor pre = rows + group_rows.index_select(0, groups);
  return {rows + kKinkMargin * at::sign(pre), group_rows, groups, at::randn({n, h}, generator, kF64)};
}

// The op's output and the gradients of sum(out * weights) in row_inputs and group_inputs, in `dtype`.
std::vector<at::Tensor> first_layer_with_gradients(const FirstLayerInputs& in, at::ScalarType dtype, bool reference) {
  const at::Tensor rows = in.rows.to(dtype).requires_grad_(true),
                   group_rows = in.group_rows.to(dtype).requires_grad_(true);
  const at::Tensor out = reference ? gathered_mlp::gathered_first_layer_reference(rows, group_rows, in.groups)
                                   : gathered_mlp::gathered_first_layer(rows, group_rows, in.groups);
  const auto grads = torch::autograd::grad({(out * in.weights.to(dtype)).sum()}, {rows, group_rows});
  return {out.detach(), grads[0], grads[1]};
}

TEST(GatheredMlpFirstLayer, IsTheCompositionWithItsGradients) {
  // Rows over several of the backward's partial tables, and an odd width and group count; the last group has no rows.
  for (const std::array<int64_t, 3>& shape : std::vector<std::array<int64_t, 3>>{{10000, 24, 7}, {37, 7, 3}}) {
    const auto [n, h, g] = shape;
    const FirstLayerInputs in = first_layer_inputs(n, h, g, g - 1, 1);
    const std::vector<at::Tensor> got = first_layer_with_gradients(in, at::kDouble, false);
    const std::vector<at::Tensor> expected = first_layer_with_gradients(in, at::kDouble, true);
    for (size_t k = 0; k < got.size(); ++k) EXPECT_LE(max_difference(got[k], expected[k]), 1e-12) << n << " " << k;
    EXPECT_EQ(got[2][g - 1].abs().max().item<double>(), 0.0) << "a group without rows has no gradient";
    EXPECT_GT(got[2].abs().max().item<double>(), 1.0);
    // Central differences of sum(out * weights) along a random direction in each input, drawn the same whatever ran
    // before (a failure reproduces).
    at::Generator draws = at::detail::createCPUGenerator(3);
    for (size_t k = 0; k < 2; ++k) {
      const at::Tensor& along = k == 0 ? in.rows : in.group_rows;
      const at::Tensor direction = at::randn(along.sizes(), draws, along.options().requires_grad(false));
      const double step = 1e-6;
      const auto at_offset = [&](double s) {
        const at::Tensor rows = k == 0 ? in.rows + s * direction : in.rows;
        const at::Tensor group_rows = k == 1 ? in.group_rows + s * direction : in.group_rows;
        return (gathered_mlp::gathered_first_layer(rows, group_rows, in.groups) * in.weights).sum().item<double>();
      };
      const double numeric = (at_offset(step) - at_offset(-step)) / (2 * step);
      // The central difference's rounding: float64's epsilon on the sum's terms, over the step.
      const double rounding = (got[0] * in.weights).abs().sum().item<double>() * 1e-16 / step;
      EXPECT_NEAR((got[k + 1] * direction).sum().item<double>(), numeric, 1e-7 * std::abs(numeric) + rounding) << k;
    }
  }
}

TEST(GatheredMlpFirstLayer, Float32FollowsFloat64) {
  const FirstLayerInputs in = first_layer_inputs(5000, 20, 5, 5, 2);
  const std::vector<at::Tensor> exact = first_layer_with_gradients(in, at::kDouble, false);
  const std::vector<at::Tensor> single = first_layer_with_gradients(in, at::kFloat, false);
  for (size_t k = 0; k < exact.size(); ++k) {
    EXPECT_EQ(single[k].scalar_type(), at::kFloat);
    EXPECT_LE(max_difference(single[k].to(at::kDouble), exact[k]), 1e-5 * exact[k].abs().max().item<double>()) << k;
  }
}

TEST(GatheredMlpFirstLayer, BackwardIsDeterministic) {
  const FirstLayerInputs in = first_layer_inputs(20000, 16, 55, 55, 3);
  const std::vector<at::Tensor> first = first_layer_with_gradients(in, at::kFloat, false);
  const std::vector<at::Tensor> second = first_layer_with_gradients(in, at::kFloat, false);
  for (size_t k = 0; k < first.size(); ++k) EXPECT_TRUE(at::equal(first[k], second[k])) << k;
}

TEST(GatheredMlpFirstLayer, MlpFinishesFromTheFirstActivation) {
  model::Mlp mlp(model::MlpShape{{5, 3}, {16, 12}, 4, false, false});
  const at::Tensor first_layer = at::randn({10, 16});
  EXPECT_TRUE(at::equal(mlp->finish(first_layer), mlp->finish_activated(at::relu(first_layer))));
  model::Mlp linear(model::MlpShape{{5}, {}, 4, false, false});
  expect_error_mentioning(
      [&] {
        linear->finish_activated(at::randn({10, 4}));
      },
      "Mlp::finish_activated: this network has no hidden layer");
}

// The structure offset's training path (the fused first layer, then finish_activated) differentiates as its function:
// central differences in float64 along a random direction of every parameter and of the fused features.
TEST(GatheredMlpFirstLayer, StructureOffsetGradientsMatchCentralDifferences) {
  // Fixed draws whatever ran before: other draws may put a ReLU's input within the step of its kink, where central
  // differences and the gradient part.
  at::manual_seed(17);
  const int64_t joints = 55, n = 200, width = 12, hidden = 16;
  const at::Tensor canonical_joints = at::randn({joints, 3}), dominant = at::randint(joints, {n}, at::kLong);
  model::StructureOffset offset(width, hidden, 4, canonical_joints, dominant);
  randomise(*offset, 0.3, 7);
  // In float64 as Python's .double() makes it: Module::to would turn the int64 dominant joints to float64 as well.
  for (at::Tensor& p : offset->parameters()) p.set_data(p.to(at::kDouble));
  for (at::Tensor& b : offset->buffers())
    if (at::isFloatingType(b.scalar_type())) b.set_data(b.to(at::kDouble));
  const at::Tensor features = at::randn({n, width}, kF64).requires_grad_(true);
  const at::Tensor rotations = at::randn({joints, 6}, kF64);
  const at::Tensor mean_weights = at::randn({n, 3}, kF64), scale_weights = at::randn({n}, kF64);
  const auto loss = [&](const at::Tensor& f) {
    const model::StructureOffsetOutput out = offset->forward(offset->project_features(f), rotations);
    return (out.mean_offset * mean_weights).sum() + (out.log_scale_offset * scale_weights).sum();
  };
  std::vector<at::Tensor> inputs = offset->parameters();
  inputs.push_back(features);
  const auto grads = torch::autograd::grad({loss(features)}, inputs);
  std::vector<at::Tensor> directions;
  double analytic = 0;
  for (size_t k = 0; k < inputs.size(); ++k) {
    directions.push_back(at::randn_like(inputs[k]));
    analytic += (grads[k] * directions.back()).sum().item<double>();
  }
  const double step = 1e-6;
  const auto at_offset = [&](double s) {
    at::NoGradGuard no_grad;
    const std::vector<at::Tensor> parameters = offset->parameters();
    for (size_t k = 0; k + 1 < inputs.size(); ++k) parameters[k].add_(s * directions[k]);
    const double value = loss(features + s * directions.back()).item<double>();
    for (size_t k = 0; k + 1 < inputs.size(); ++k) parameters[k].sub_(s * directions[k]);
    return value;
  };
  const double numeric = (at_offset(step) - at_offset(-step)) / (2 * step);
  EXPECT_NEAR(analytic, numeric, 1e-6 * std::abs(numeric) + 1e-9);
}

TEST(GatheredMlpFirstLayer, GroupsOutOfRangeAreClearErrors) {
  const at::Tensor rows = at::randn({8, 4}, kF64), group_rows = at::randn({3, 4}, kF64);
  for (int64_t bad : {int64_t(3), int64_t(-1)}) {
    at::Tensor groups = at::randint(3, {8}, at::kLong);
    groups[5] = bad;
    expect_error_mentioning(
        [&] { gathered_mlp::gathered_first_layer(rows, group_rows, groups); },
        "gathered_first_layer: groups must lie in [0, 3), got " + std::to_string(bad) + " at row 5");
  }
}

TEST(GatheredMlpFirstLayer, BadInputsAreClearErrors) {
  const at::Tensor rows = at::randn({8, 4}, kF64), group_rows = at::randn({3, 4}, kF64);
  const at::Tensor groups = at::randint(3, {8}, at::kLong);
  using gathered_mlp::gathered_first_layer;
  expect_error_mentioning([&] { gathered_first_layer(rows.to(at::kInt), group_rows, groups); },
                          "gathered_first_layer: row_inputs must be a float or double (N, H) tensor, got a Int");
  expect_error_mentioning([&] { gathered_first_layer(rows.flatten(), group_rows, groups); },
                          "row_inputs must be a float or double (N, H) tensor, got a Double tensor of shape [32]");
  expect_error_mentioning([&] { gathered_first_layer(rows, group_rows.narrow(1, 0, 3), groups); },
                          "gathered_first_layer: group_inputs must be a Double (G, 4) tensor with G >= 1 on cpu, got "
                          "a Double tensor of shape [3, 3]");
  expect_error_mentioning([&] { gathered_first_layer(rows, group_rows.narrow(0, 0, 0), groups); },
                          "group_inputs must be a Double (G, 4) tensor with G >= 1");
  expect_error_mentioning([&] { gathered_first_layer(rows, group_rows.to(at::kFloat), groups); },
                          "group_inputs must be a Double (G, 4) tensor with G >= 1 on cpu, got a Float");
  expect_error_mentioning([&] { gathered_first_layer(rows, group_rows, groups.to(at::kInt)); },
                          "gathered_first_layer: groups must be an int64 (8) tensor on cpu, got a Int");
  expect_error_mentioning([&] { gathered_first_layer(rows, group_rows, groups.narrow(0, 0, 7)); },
                          "groups must be an int64 (8) tensor on cpu, got a Long tensor of shape [7]");
}

TEST(GatheredMlp, IsADispatcherOpWhoseMetaKernelDescribesItsOutput) {
  expect_backend_kernels("sfgs::gathered_mlp", true);  // its Autograd kernel refuses a gradient
  const int64_t n = 7, h = 4;
  const std::vector<c10::IValue> arguments = {at::randn({n, h}), at::randn({3, h}), at::randint(3, {n}, at::kLong),
                                              at::randn({h, h}), at::randn({h}),    at::randn({2, h}),
                                              at::randn({2})};
  at::NoGradGuard no_grad;
  expect_meta_describes_cpu("sfgs::gathered_mlp", arguments);
  const at::Tensor out = call_boxed(registered_op("sfgs::gathered_mlp"), arguments)[0].toTensor();
  const gathered_mlp::GatheredMlpWeights w{arguments[3].toTensor(), arguments[4].toTensor(), arguments[5].toTensor(),
                                           arguments[6].toTensor()};
  EXPECT_TRUE(at::equal(out, gathered_mlp::gathered_mlp_reference(arguments[0].toTensor(), arguments[1].toTensor(),
                                                                  arguments[2].toTensor(), w)));
  std::vector<c10::IValue> outside = arguments;
  outside[2] = arguments[2].toTensor() + 3;
  EXPECT_THROW(call_boxed(registered_op("sfgs::gathered_mlp"), outside), c10::Error);
}

TEST(GatheredFirstLayer, IsADispatcherOpWhoseMetaKernelsDescribeItsOutputs) {
  expect_backend_kernels("sfgs::gathered_first_layer", true);
  expect_backend_kernels("sfgs::gathered_first_layer_backward", false);
  const at::Tensor rows = at::randn({11, 6}, kF64), group_rows = at::randn({4, 6}, kF64);
  const at::Tensor groups = at::randint(0, 4, {11}, at::TensorOptions().dtype(at::kLong));
  expect_meta_describes_cpu("sfgs::gathered_first_layer", {rows, group_rows, groups});
  const at::Tensor out =
      call_boxed(registered_op("sfgs::gathered_first_layer"), {rows, group_rows, groups})[0].toTensor();
  EXPECT_TRUE(at::equal(out, gathered_mlp::gathered_first_layer_reference(rows, group_rows, groups)));
  expect_meta_describes_cpu("sfgs::gathered_first_layer_backward", {at::randn({11, 6}, kF64), out, groups, int64_t(4)});
  // Every group index past the last group row, so the check cannot pass by chance.
  EXPECT_THROW(call_boxed(registered_op("sfgs::gathered_first_layer"), {rows, group_rows, groups + 4}), c10::Error);
}

}  // namespace
}  // namespace sfgs::testing
