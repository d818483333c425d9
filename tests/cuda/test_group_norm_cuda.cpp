// The fused GroupNorm + ReLU op's CUDA kernels (ops/group_norm/group_norm.h) against its CPU backend: float64 parity of
// the forward and of every gradient over the group layouts the kernels take, float32 at the avatar's size, a layout
// the kernels do not take (the reference), and a small case for compute-sanitizer. Skips without a CUDA device.
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "model/constants.h"
#include "ops/group_norm/group_norm.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using group_norm::group_norm_relu;

struct Result {
  at::Tensor out;
  std::vector<at::Tensor> grads;  // pre, gamma, beta, bias
};

// The op on `device` in `dtype`, from the same float64 CPU draws, with the gradients of sum(out * weights).
Result run_on(at::Device device, at::ScalarType dtype, int64_t rows, int64_t channels, int64_t groups, bool bias,
              uint64_t seed) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const auto move = [&](const at::Tensor& t) { return t.to(device, dtype).requires_grad_(true); };
  const at::Tensor pre = move(at::randn({rows, channels}, g, f64));
  const at::Tensor b = bias ? move(at::randn({channels}, g, f64)) : at::Tensor();
  const at::Tensor gamma = move(1 + 0.5 * at::randn({channels}, g, f64));
  const at::Tensor beta = move(0.3 * at::randn({channels}, g, f64));
  const at::Tensor weights = at::randn({rows, channels}, g, f64).to(device, dtype);
  Result r;
  r.out = group_norm_relu(pre, b, gamma, beta, groups, kMlpGroupNormEpsilon);
  std::vector<at::Tensor> inputs{pre, gamma, beta};
  if (bias) inputs.push_back(b);
  r.grads = torch::autograd::grad({(r.out * weights).sum()}, inputs);
  r.out = r.out.detach().to(at::kCPU, at::kDouble);
  for (at::Tensor& t : r.grads) t = t.to(at::kCPU, at::kDouble);
  return r;
}

void expect_parity(int64_t rows, int64_t channels, int64_t groups, bool bias, double tolerance) {
  const Result cpu = run_on(at::kCPU, at::kDouble, rows, channels, groups, bias, 3);
  const Result gpu = run_on(at::kCUDA, at::kDouble, rows, channels, groups, bias, 3);
  const std::string what = std::to_string(rows) + " x " + std::to_string(channels) + " in " + std::to_string(groups);
  EXPECT_LT(max_difference(gpu.out, cpu.out), tolerance) << what;
  for (size_t k = 0; k < cpu.grads.size(); ++k)
    EXPECT_LT(max_difference(gpu.grads[k], cpu.grads[k]), 100 * tolerance) << what << ", gradient " << k;
}

TEST(GroupNormReluCuda, MatchesTheCpuBackendInFloat64) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  struct Layout {
    int64_t channels, groups;
  };
  for (const Layout l :
       {Layout{32, 1}, Layout{64, 2}, Layout{96, 3}, Layout{128, 4}, Layout{128, 1}, Layout{256, 8}, Layout{256, 4}}) {
    ASSERT_TRUE(group_norm::fuses(at::empty({1, l.channels}, at::kCUDA), l.groups)) << l.channels;
    for (const bool bias : {true, false}) expect_parity(4099, l.channels, l.groups, bias, 1e-12);
  }
}

// float32 (128 channels: the float4 kernels; others: the per-slab ones) against float64 on the GPU. An element whose
// affine output lies within float32's rounding of 0 may fall on the other side of the ReLU, which changes its own
// gradient (by up to |gamma go rstd|) and its group's: those rows (a few in a thousand) are left out of the
// elementwise comparison, and the column sums over all rows, which they enter, get a looser bound.
void expect_float32_close(int64_t rows, int64_t channels, int64_t groups, bool bias) {
  const Result exact = run_on(at::kCUDA, at::kDouble, rows, channels, groups, bias, 9);
  const Result f32 = run_on(at::kCUDA, at::kFloat, rows, channels, groups, bias, 9);
  const std::string what = std::to_string(rows) + " x " + std::to_string(channels) + " in " + std::to_string(groups);
  EXPECT_LT(max_difference(f32.out, exact.out), 2e-5) << what;
  // The float64 affine output, from the same draws: a row with an element near the kink.
  at::Generator g = at::detail::createCPUGenerator(9);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor pre = at::randn({rows, channels}, g, f64);
  const at::Tensor b = bias ? at::randn({channels}, g, f64) : at::zeros({channels}, f64);
  const at::Tensor gamma = 1 + 0.5 * at::randn({channels}, g, f64), beta = 0.3 * at::randn({channels}, g, f64);
  const at::Tensor normalised = at::group_norm(pre + b, groups, {}, {}, kMlpGroupNormEpsilon);
  const at::Tensor near_kink = ((normalised * gamma + beta).abs() < 1e-5).any(1);
  EXPECT_LT(near_kink.sum().item<int64_t>(), std::max<int64_t>(1, rows / 100)) << what;
  const at::Tensor kept = near_kink.logical_not();
  const double pre_scale = std::max(1.0, exact.grads[0].abs().max().item<double>());
  EXPECT_LT(max_difference(f32.grads[0].index({kept}), exact.grads[0].index({kept})) / pre_scale, 2e-5) << what;
  for (size_t k = 1; k < exact.grads.size(); ++k) {
    const double scale = std::max(1.0, exact.grads[k].abs().max().item<double>());
    EXPECT_LT(max_difference(f32.grads[k], exact.grads[k]) / scale, 5e-3) << what << " column sums " << k;
  }
}

// The avatar's layer at its size in float32 against float64 (the column sums run over 250k rows), with the float4
// kernels' other group sizes and the per-slab kernels' widths.
TEST(GroupNormReluCuda, Float32AtTheAvatarsSize) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_float32_close(250000, 128, 4, true);
  expect_float32_close(20000, 128, 2, false);
  expect_float32_close(20000, 128, 1, true);
  expect_float32_close(20000, 256, 8, true);
  expect_float32_close(20000, 96, 3, false);
}

// Groups of 16 channels are not the kernels' (a group is a warp's multiple): the LibTorch reference, same results.
TEST(GroupNormReluCuda, OtherLayoutsTakeTheReference) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  EXPECT_FALSE(group_norm::fuses(at::empty({1, 64}, at::kCUDA), 4));
  expect_parity(300, 64, 4, true, 1e-12);
}

// The layer with its linear map (the product recomputed in the backward): CUDA against the CPU in float64.
TEST(GroupNormReluCuda, LinearLayerMatchesTheCpuBackend) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  at::Generator g = at::detail::createCPUGenerator(31);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const std::vector<at::Tensor> draws{at::randn({5000, 128}, g, f64), 0.1 * at::randn({128, 128}, g, f64),
                                      at::randn({128}, g, f64), 1 + 0.5 * at::randn({128}, g, f64),
                                      0.3 * at::randn({128}, g, f64)};
  const at::Tensor weights = at::randn({5000, 128}, g, f64);
  std::vector<std::vector<at::Tensor>> results;
  for (const at::Device device : {at::Device(at::kCPU), at::Device(at::kCUDA)}) {
    std::vector<at::Tensor> in;
    for (const at::Tensor& d : draws) in.push_back(d.to(device).requires_grad_(true));
    const at::Tensor out =
        group_norm::linear_group_norm_relu(in[0], in[1], in[2], in[3], in[4], 4, kMlpGroupNormEpsilon);
    std::vector<at::Tensor> r{out.detach().cpu()};
    for (const at::Tensor& grad : torch::autograd::grad({(out * weights.to(device)).sum()}, in))
      r.push_back(grad.cpu());
    results.push_back(r);
  }
  for (size_t k = 0; k < results[0].size(); ++k)
    EXPECT_LT(max_difference(results[1][k], results[0][k]), k == 0 ? 1e-12 : 1e-9) << "output " << k;
}

// Small enough for compute-sanitizer (memcheck, racecheck): rows fewer than a block's warps, and a grid-stride loop.
TEST(GroupNormCudaSanitizer, SmallRows) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_parity(3, 128, 4, true, 1e-12);
  expect_parity(2000, 64, 2, false, 1e-12);
  expect_float32_close(3, 128, 4, true);  // the float4 kernels
  expect_float32_close(2000, 128, 1, false);
}

}  // namespace
}  // namespace sfgs::testing
