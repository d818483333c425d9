// The feature-fusion ops (ops/feature_fusion/feature_fusion.h) on the CPU backend: the gated mix against its LibTorch
// composition (values, autograd gradients, central differences in float64, logits far beyond the sigmoid's range),
// the row merge against cat + index_select (values and gradients exactly, an empty subset), and the errors at their
// boundary.
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "ops/feature_fusion/feature_fusion.h"
#include "test_metrics_support.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using feature_fusion::MergeOrder;

std::vector<at::Tensor> mix_inputs(int64_t rows, int64_t columns, uint64_t seed, double logit_scale = 3) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  return {(at::randn({rows, columns}, g, kF64) * logit_scale).requires_grad_(true),
          at::randn({rows, columns}, g, kF64).requires_grad_(true),
          at::randn({rows, columns}, g, kF64).requires_grad_(true)};
}

TEST(FeatureFusion, GatedMixIsTheCompositionWithItsGradients) {
  const std::vector<at::Tensor> in = mix_inputs(300, 96, 1);
  const at::Tensor got = feature_fusion::gated_mix(in[0], in[1], in[2]);
  const at::Tensor expected = feature_fusion::gated_mix_reference(in[0], in[1], in[2]);
  EXPECT_LT(max_difference(got, expected), 1e-14);
  // Fixed draws whatever ran before, so that a failure reproduces.
  at::Generator draws = at::detail::createCPUGenerator(2);
  const at::Tensor weights = at::randn(expected.sizes(), draws, kF64);
  const auto grads = torch::autograd::grad({(got * weights).sum()}, in);
  const auto expected_grads = torch::autograd::grad({(expected * weights).sum()}, in);
  for (size_t k = 0; k < in.size(); ++k) EXPECT_LT(max_difference(grads[k], expected_grads[k]), 1e-13) << k;
  // Central differences of <weights, mix> along a random direction in each input.
  for (size_t k = 0; k < in.size(); ++k) {
    const at::Tensor direction = at::randn(in[k].sizes(), draws, kF64);
    const double step = 1e-6;
    const auto at_offset = [&](double s) {
      std::vector<at::Tensor> moved = {in[0].detach(), in[1].detach(), in[2].detach()};
      moved[k] = moved[k] + s * direction;
      return (feature_fusion::gated_mix(moved[0], moved[1], moved[2]) * weights).sum().item<double>();
    };
    const double numeric = (at_offset(step) - at_offset(-step)) / (2 * step);
    // The central difference's rounding: float64's epsilon on the sum's terms, over the step.
    const double rounding = (expected * weights).abs().sum().item<double>() * 1e-16 / step;
    EXPECT_NEAR((grads[k] * direction).sum().item<double>(), numeric, 1e-7 * std::abs(numeric) + rounding) << k;
  }
}

TEST(FeatureFusion, GatedMixTakesLogitsFarBeyondTheSigmoidsRange) {
  const std::vector<at::Tensor> in = mix_inputs(4, 8, 2);
  for (double logit : {-1e4, 1e4}) {
    const at::Tensor logits = at::full({4, 8}, logit, kF64).requires_grad_(true);
    const at::Tensor out = feature_fusion::gated_mix(logits, in[1], in[2]);
    EXPECT_EQ(max_difference(out, logit > 0 ? in[2] : in[1]), 0.0) << logit;
    const auto grads = torch::autograd::grad({out.sum()}, {logits, in[1], in[2]});
    for (const at::Tensor& g : grads) EXPECT_TRUE(at::isfinite(g).all().item<bool>()) << logit;
    EXPECT_EQ(grads[0].abs().max().item<double>(), 0.0);
  }
}

TEST(FeatureFusion, GatedMixInFloat32FollowsFloat64) {
  const std::vector<at::Tensor> in = mix_inputs(257, 3, 3);  // an odd count
  const at::Tensor exact = feature_fusion::gated_mix(in[0], in[1], in[2]);
  const at::Tensor single = feature_fusion::gated_mix(in[0].to(at::kFloat), in[1].to(at::kFloat), in[2].to(at::kFloat));
  EXPECT_EQ(single.scalar_type(), at::kFloat);
  EXPECT_LT(max_difference(single.to(at::kDouble), exact), 1e-5);
}

// A random split of `rows` points into two subsets (points of each in a random order).
std::pair<at::Tensor, at::Tensor> random_subsets(int64_t rows, int64_t first, uint64_t seed) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  const at::Tensor points = at::randperm(rows, g, at::TensorOptions().dtype(at::kLong));
  return {points.narrow(0, 0, first).clone(), points.narrow(0, first, rows - first).clone()};
}

TEST(FeatureFusion, MergeRowsIsCatIndexSelectWithItsGradient) {
  for (const auto& [rows, first] : std::vector<std::pair<int64_t, int64_t>>{{1000, 700}, {50, 50}, {9, 0}}) {
    const auto [first_points, second_points] = random_subsets(rows, first, 4);
    const MergeOrder order = MergeOrder::of(first_points, second_points);
    for (at::ScalarType dtype : {at::kDouble, at::kFloat}) {
      at::Generator g = at::detail::createCPUGenerator(5);
      const at::Tensor a = at::randn({first, 96}, g, kF64).to(dtype).requires_grad_(true);
      const at::Tensor b = at::randn({rows - first, 96}, g, kF64).to(dtype).requires_grad_(true);
      const at::Tensor got = feature_fusion::merge_rows(a, b, order);
      const at::Tensor expected = feature_fusion::merge_rows_reference(a, b, order);
      EXPECT_EQ(max_difference(got, expected), 0.0) << rows << " " << dtype;
      // Point i's row is row i of the merge: the first subset's rows land on first_points.
      if (first > 0) EXPECT_EQ(max_difference(got.index_select(0, first_points), a), 0.0);
      const at::Tensor weights = at::randn(expected.sizes(), g, kF64).to(dtype);
      const auto grads = torch::autograd::grad({(got * weights).sum()}, {a, b}, {}, false, false, true);
      const auto expected_grads = torch::autograd::grad({(expected * weights).sum()}, {a, b}, {}, false, false, true);
      for (size_t k = 0; k < 2; ++k) EXPECT_EQ(max_difference(grads[k], expected_grads[k]), 0.0) << k;
    }
  }
}

// The planes' samples arrive as transposed views (column stride N): they are merged as they are, not copied first.
TEST(FeatureFusion, MergeRowsReadsTransposedRows) {
  const auto [first_points, second_points] = random_subsets(300, 200, 6);
  const MergeOrder order = MergeOrder::of(first_points, second_points);
  at::Generator g = at::detail::createCPUGenerator(7);
  const at::Tensor a = at::randn({96, 200}, g, kF64).t().requires_grad_(true);
  const at::Tensor b = at::randn({96, 100}, g, kF64).t().requires_grad_(true);
  ASSERT_FALSE(a.is_contiguous());
  const at::Tensor got = feature_fusion::merge_rows(a, b, order);
  EXPECT_TRUE(got.is_contiguous());
  EXPECT_EQ(max_difference(got, feature_fusion::merge_rows_reference(a, b, order)), 0.0);
  const at::Tensor weights = at::randn(got.sizes(), g, kF64);
  const auto grads = torch::autograd::grad({(got * weights).sum()}, {a, b});
  EXPECT_EQ(max_difference(grads[0], weights.index_select(0, first_points)), 0.0);
  EXPECT_EQ(max_difference(grads[1], weights.index_select(0, second_points)), 0.0);
}

TEST(FeatureFusion, MergeOrderRefusesSubsetsThatAreNotAPartition) {
  const auto longs = [](std::vector<int64_t> v) { return at::tensor(v, at::TensorOptions().dtype(at::kLong)); };
  expect_error([&] { MergeOrder::of(longs({0, 2}), longs({2, 1})); }, {"MergeOrder: point 2 is in the subsets twice"});
  expect_error([&] { MergeOrder::of(longs({0, 3}), longs({1})); }, {"MergeOrder: point 3 is outside 0..2"});
  expect_error([&] { MergeOrder::of(longs({0}), at::zeros({2}, at::kFloat)); },
               {"MergeOrder: the subsets' points must be int64 (K) tensors", "Float"});
}

TEST(FeatureFusion, BadInputsAreClearErrors) {
  const at::Tensor x = at::randn({4, 6}, kF64);
  expect_error([&] { feature_fusion::gated_mix(x, x, x.narrow(1, 0, 5)); },
               {"gated_mix: logits, a and b must share a's shape [4, 6]", "[4, 5]"});
  expect_error([&] { feature_fusion::gated_mix(x, x.to(at::kInt), x); }, {"gated_mix: a must be a float or double"});
  expect_error([&] { feature_fusion::gated_mix(x.to(at::kFloat), x, x); }, {"dtype Double", "Float"});
  const at::Tensor meta = at::empty({4, 6}, at::TensorOptions().dtype(at::kDouble).device(at::kMeta));
  expect_error([&] { feature_fusion::gated_mix(meta, meta, meta); },
               {"gated_mix: tensors must be on the CPU or a CUDA device, got meta"});
  const auto longs = [](std::vector<int64_t> v) { return at::tensor(v, at::TensorOptions().dtype(at::kLong)); };
  const MergeOrder order = MergeOrder::of(longs({1, 3}), longs({0, 2}));
  expect_error([&] { feature_fusion::merge_rows(x.narrow(0, 0, 3), x.narrow(0, 0, 1), order); },
               {"merge_rows: the order was made for 2 rows of the first subset, got 3"});
  expect_error([&] { feature_fusion::merge_rows(x.narrow(0, 0, 2), x.narrow(0, 0, 3), order); },
               {"merge_rows: the order must be int64 (5) tensors"});
  expect_error([&] { feature_fusion::merge_rows(x.narrow(0, 0, 2), x.narrow(0, 0, 2).narrow(1, 0, 5), order); },
               {"merge_rows: second must be a Double (N2, 6) tensor"});
}

TEST(FeatureFusion, TheOpsAreDispatcherOpsWhoseMetaKernelsDescribeTheirOutputs) {
  for (const char* name : {"sfgs::gated_mix", "sfgs::merge_rows"}) expect_backend_kernels(name, true);
  for (const char* name : {"sfgs::gated_mix_backward", "sfgs::merge_rows_backward"})
    expect_backend_kernels(name, false);
  const std::vector<at::Tensor> mix = mix_inputs(6, 5, 3);
  expect_meta_describes_cpu("sfgs::gated_mix", {mix[0], mix[1], mix[2]});
  expect_meta_describes_cpu("sfgs::gated_mix_backward", {at::randn({6, 5}, kF64), mix[0], mix[1], mix[2]});
  try {
    call_boxed(registered_op("sfgs::gated_mix_backward"), {at::randn({6, 4}, kF64), mix[0], mix[1], mix[2]});
    ADD_FAILURE() << "a gradient of the wrong shape was taken";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what_without_backtrace()).find("gated_mix_backward: grad must share a's shape"),
              std::string::npos)
        << e.what_without_backtrace();
  }
  const auto [first_points, second_points] = random_subsets(9, 4, 5);
  const feature_fusion::MergeOrder order = feature_fusion::MergeOrder::of(first_points, second_points);
  const at::Tensor first = at::randn({4, 3}, kF64), second = at::randn({5, 3}, kF64);
  expect_meta_describes_cpu("sfgs::merge_rows", {first, second, order.source, order.inverse});
  expect_meta_describes_cpu("sfgs::merge_rows_backward", {at::randn({9, 3}, kF64), order.inverse, int64_t(4)});
}

TEST(FeatureFusion, AMergeSourceOutOfRangeGivesANanRow) {
  const auto [first_points, second_points] = random_subsets(9, 4, 6);
  const feature_fusion::MergeOrder order = feature_fusion::MergeOrder::of(first_points, second_points);
  const at::Tensor first = at::randn({4, 3}, kF64), second = at::randn({5, 3}, kF64);
  at::Tensor source = order.source.clone();
  source[2] = 9;
  source[5] = -1;
  const at::Tensor merged =
      call_boxed(registered_op("sfgs::merge_rows"), {first, second, source, order.inverse})[0].toTensor();
  const at::Tensor expected = feature_fusion::merge_rows_reference(first, second, order);
  for (int64_t row = 0; row < 9; ++row) {
    if (row == 2 || row == 5)
      EXPECT_TRUE(merged[row].isnan().all().item<bool>()) << row;
    else
      EXPECT_TRUE(at::equal(merged[row], expected[row])) << row;
  }
}

}  // namespace
}  // namespace sfgs::testing
