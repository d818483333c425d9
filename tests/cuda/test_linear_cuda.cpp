// The linear layer's CUDA column sum (ops/linear/linear.h) against at::sum in float64 and float32 at the networks'
// sizes (215,782 rows of 128, 96 and 3 columns; the fused GroupNorm's partial rows) and odd ones, the same bits on
// every run, the layer's gradients on CUDA against at::linear's, and small cases for compute-sanitizer. Skips without a
// CUDA device.
#include <algorithm>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "ops/linear/linear.h"

namespace sfgs::testing {
namespace {

double relative_difference(const at::Tensor& a, const at::Tensor& b) {
  const at::Tensor x = a.to(at::kCPU, at::kDouble), y = b.to(at::kCPU, at::kDouble);
  return (x - y).abs().max().item<double>() / std::max(1e-300, y.abs().max().item<double>());
}

void expect_column_sums(int64_t rows, int64_t columns) {
  at::Generator g = at::detail::createCPUGenerator(uint64_t(rows * 31 + columns));
  const at::Tensor exact = at::randn({rows, columns}, g, at::TensorOptions().dtype(at::kDouble)) + 0.5;
  const at::Tensor expected = exact.sum(0);
  const at::Tensor on_device = exact.to(at::kCUDA);
  const at::Tensor sum = linear::column_sum(on_device);
  EXPECT_LT(relative_difference(sum, expected), 1e-12) << rows << " x " << columns;
  EXPECT_TRUE(at::equal(sum, linear::column_sum(on_device))) << "not the same bits twice";
  const at::Tensor single = linear::column_sum(on_device.to(at::kFloat));
  EXPECT_EQ(single.scalar_type(), at::kFloat);
  EXPECT_LT(relative_difference(single, expected), 2e-5) << rows << " x " << columns;
}

TEST(LinearCuda, ColumnSumsMatchAtSum) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  for (const auto& [rows, columns] : std::vector<std::pair<int64_t, int64_t>>{
           {215782, 128}, {215782, 96}, {215782, 3}, {528, 384}, {1000, 33}, {65, 1}, {1, 5}})
    expect_column_sums(rows, columns);
  EXPECT_EQ(linear::column_sum(at::zeros({0, 4}, at::kCUDA)).abs().sum().item<double>(), 0.0);
  EXPECT_EQ(linear::column_sum(at::zeros({5, 0}, at::kCUDA)).numel(), 0);
}

TEST(LinearCuda, GradientsMatchAtLinear) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  at::Generator g = at::detail::createCPUGenerator(8);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor x = at::randn({20000, 96}, g, f64).to(at::kCUDA).requires_grad_(true);
  const at::Tensor weight = at::randn({128, 96}, g, f64).to(at::kCUDA).requires_grad_(true);
  const at::Tensor bias = at::randn({128}, g, f64).to(at::kCUDA).requires_grad_(true);
  const at::Tensor weights = at::randn({20000, 128}, g, f64).to(at::kCUDA);
  const auto grads = torch::autograd::grad({(linear::linear(x, weight, bias) * weights).sum()}, {x, weight, bias});
  const auto expected = torch::autograd::grad({(at::linear(x, weight, bias) * weights).sum()}, {x, weight, bias});
  for (size_t k = 0; k < grads.size(); ++k) EXPECT_LT(relative_difference(grads[k], expected[k]), 1e-12) << k;
}

TEST(LinearCudaSanitizer, SmallColumnSums) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_column_sums(300, 40);
  expect_column_sums(3, 2);
}

}  // namespace
}  // namespace sfgs::testing
