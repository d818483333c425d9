// The networks' linear layer (ops/linear/linear.h) against at::linear: values and every gradient in float64, with and
// without a bias and with inputs that need no gradient; the column sum against at::sum; the errors at the boundary.
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "ops/linear/linear.h"
#include "test_metrics_support.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

TEST(Linear, EqualsAtLinearWithEveryGradient) {
  at::Generator g = at::detail::createCPUGenerator(3);
  const at::Tensor x = at::randn({700, 24}, g, kF64).requires_grad_(true);
  const at::Tensor weight = at::randn({16, 24}, g, kF64).requires_grad_(true);
  const at::Tensor bias = at::randn({16}, g, kF64).requires_grad_(true);
  const at::Tensor weights = at::randn({700, 16}, g, kF64);
  for (bool with_bias : {true, false}) {
    const at::Tensor b = with_bias ? bias : at::Tensor();
    const at::Tensor got = linear::linear(x, weight, b), expected = at::linear(x, weight, b);
    EXPECT_LT(max_difference(got, expected), 1e-12) << with_bias;
    std::vector<at::Tensor> inputs = {x, weight};
    if (with_bias) inputs.push_back(bias);
    const auto grads = torch::autograd::grad({(got * weights).sum()}, inputs);
    const auto expected_grads = torch::autograd::grad({(expected * weights).sum()}, inputs);
    for (size_t k = 0; k < inputs.size(); ++k)
      EXPECT_LT(max_difference(grads[k], expected_grads[k]), 1e-10) << with_bias << " " << k;
  }
  // An input that needs no gradient gets none, the others theirs.
  const at::Tensor fixed = x.detach();
  const auto grads = torch::autograd::grad({(linear::linear(fixed, weight, bias) * weights).sum()}, {weight, bias});
  EXPECT_LT(max_difference(grads[1], weights.sum(0)), 1e-10);
}

TEST(Linear, ColumnSumIsTheSumOverRows) {
  at::Generator g = at::detail::createCPUGenerator(4);
  const at::Tensor rows = at::randn({1000, 7}, g, kF64);
  EXPECT_LT(max_difference(linear::column_sum(rows), rows.sum(0)), 1e-12);
  EXPECT_EQ(linear::column_sum(at::zeros({0, 3}, kF64)).sizes(), at::IntArrayRef({3}));
}

TEST(Linear, BadInputsAreClearErrors) {
  const at::Tensor x = at::randn({4, 6}, kF64), weight = at::randn({3, 6}, kF64);
  expect_error([&] { linear::linear(x, weight.narrow(1, 0, 5), at::Tensor()); },
               {"linear: weight must be a Double (O, 6) tensor", "[3, 5]"});
  expect_error([&] { linear::linear(x, weight, at::zeros({4}, kF64)); }, {"linear: bias must be a Double (3) tensor"});
  expect_error([&] { linear::linear(x.flatten(), weight, at::Tensor()); }, {"linear: x must be a floating (N, I)"});
  expect_error([&] { linear::column_sum(at::zeros({4}, kF64)); }, {"column_sum: rows must be a floating (R, C)"});
}

TEST(Linear, TheOpsAreDispatcherOpsWhoseMetaKernelsDescribeTheirOutputs) {
  expect_backend_kernels("sfgs::linear", true);
  expect_backend_kernels("sfgs::column_sum", false);
  const at::Tensor x = at::randn({7, 5}, kF64), weight = at::randn({3, 5}, kF64), bias = at::randn({3}, kF64);
  for (const c10::IValue& b : {c10::IValue(bias), c10::IValue()})
    expect_meta_describes_cpu("sfgs::linear", {x, weight, b});
  expect_meta_describes_cpu("sfgs::column_sum", {x});
  EXPECT_TRUE(at::equal(call_boxed(registered_op("sfgs::linear"), {x, weight, bias})[0].toTensor(),
                        linear::linear(x, weight, bias)));
  EXPECT_THROW(call_boxed(registered_op("sfgs::linear"), {x, weight.t().contiguous(), bias}), c10::Error);
}

}  // namespace
}  // namespace sfgs::testing
