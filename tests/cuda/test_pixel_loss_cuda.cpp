// The fused pixel-loss op's CUDA kernels (ops/pixel_loss/pixel_loss.h) against its CPU backend: float64 parity of the
// four means and the prediction's gradient at training sizes and odd ones, float32 at 800 x 1200 against float64,
// and a small case for compute-sanitizer. Skips without a CUDA device.
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "ops/pixel_loss/pixel_loss.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

std::pair<at::Tensor, at::Tensor> run_on(at::Device device, at::ScalarType dtype, int64_t height, int64_t width,
                                         uint64_t seed) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor prediction =
      (at::rand({height, width, 3}, g, f64) * 1.2 - 0.1).to(device, dtype).requires_grad_(true);
  const at::Tensor target = at::rand({height, width, 3}, g, f64).to(device, dtype);
  const at::Tensor weights = (at::rand({4}, g, f64) + 0.5).to(device, dtype);
  const at::Tensor means = pixel_loss::pixel_losses(prediction, target);
  const at::Tensor grad = torch::autograd::grad({(means * weights).sum()}, {prediction})[0];
  return {means.detach().to(at::kCPU, at::kDouble), grad.to(at::kCPU, at::kDouble)};
}

// Relative to the largest value of b.
double relative_difference(const at::Tensor& a, const at::Tensor& b) {
  return max_difference(a, b) / b.abs().max().item<double>();
}

TEST(PixelLossCuda, MatchesTheCpuBackendInFloat64) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  for (const auto& [height, width] : {std::pair{1200, 800}, std::pair{33, 17}, std::pair{2, 300}}) {
    const auto [cpu_means, cpu_grad] = run_on(at::kCPU, at::kDouble, height, width, 3);
    const auto [gpu_means, gpu_grad] = run_on(at::kCUDA, at::kDouble, height, width, 3);
    EXPECT_LT(max_difference(gpu_means, cpu_means), 1e-12) << height << " x " << width;
    EXPECT_LT(relative_difference(gpu_grad, cpu_grad), 1e-10) << height << " x " << width;
  }
}

TEST(PixelLossCuda, Float32AtTrainingSize) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const auto [exact_means, exact_grad] = run_on(at::kCUDA, at::kDouble, 1200, 800, 5);
  const auto [means, grad] = run_on(at::kCUDA, at::kFloat, 1200, 800, 5);
  EXPECT_LT(max_difference(means, exact_means), 1e-5);
  // A pixel whose difference is within float32's rounding of 0 may take the other sign: compare on average.
  EXPECT_LT((grad - exact_grad).abs().mean().item<double>() / exact_grad.abs().mean().item<double>(), 1e-4);
}

TEST(PixelLossCudaSanitizer, SmallImages) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const auto [cpu_means, cpu_grad] = run_on(at::kCPU, at::kDouble, 3, 5, 1);
  const auto [gpu_means, gpu_grad] = run_on(at::kCUDA, at::kDouble, 3, 5, 1);
  EXPECT_LT(max_difference(gpu_means, cpu_means), 1e-12);
  EXPECT_LT(relative_difference(gpu_grad, cpu_grad), 1e-10);
}

}  // namespace
}  // namespace sfgs::testing
