// The feature-fusion ops' CUDA kernels (ops/feature_fusion/feature_fusion.h) against the CPU backend: float64 parity of
// the gated mix and the row merge with their gradients at the training size (215,782 points, 96 channels) and odd
// shapes, float32 through the float4 paths and through the scalar ones (unaligned and odd-width arrays), and small
// cases for compute-sanitizer. Skips without a CUDA device.
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/core/dispatch/Dispatcher.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "ops/feature_fusion/feature_fusion.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using feature_fusion::MergeOrder;

// The mix and its gradients (logits, a, b) of `inputs` (float64 CPU) run on `device` in `dtype`, as float64 CPU.
// `offset` > 0 starts every array that many values into a larger one (no float4 path).
std::vector<at::Tensor> mix_on(const std::vector<at::Tensor>& inputs, const at::Tensor& weights, at::Device device,
                               at::ScalarType dtype, int64_t offset = 0) {
  std::vector<at::Tensor> in;
  for (const at::Tensor& t : inputs) {
    const at::Tensor flat = at::zeros({t.numel() + offset}, at::TensorOptions().dtype(dtype).device(device));
    flat.narrow(0, offset, t.numel()).copy_(t.flatten());
    in.push_back(flat.narrow(0, offset, t.numel()).view(t.sizes()).requires_grad_(true));
  }
  const at::Tensor out = feature_fusion::gated_mix(in[0], in[1], in[2]);
  const auto grads = torch::autograd::grad({(out * weights.to(device, dtype)).sum()}, in);
  return {out.detach().to(at::kCPU, at::kDouble), grads[0].to(at::kCPU, at::kDouble),
          grads[1].to(at::kCPU, at::kDouble), grads[2].to(at::kCPU, at::kDouble)};
}

std::vector<at::Tensor> random_rows(int64_t rows, int64_t columns, int count, uint64_t seed) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  std::vector<at::Tensor> out;
  for (int k = 0; k < count; ++k)
    out.push_back(at::randn({rows, columns}, g, at::TensorOptions().dtype(at::kDouble)) * (k == 0 ? 4.0 : 1.0));
  return out;
}

void expect_mix_parity(int64_t rows, int64_t columns) {
  const std::vector<at::Tensor> in = random_rows(rows, columns, 4, 7);  // logits, a, b, weights
  const std::vector<at::Tensor> cpu = mix_on({in[0], in[1], in[2]}, in[3], at::kCPU, at::kDouble);
  const std::vector<at::Tensor> gpu = mix_on({in[0], in[1], in[2]}, in[3], at::kCUDA, at::kDouble);
  for (size_t k = 0; k < cpu.size(); ++k) EXPECT_LT(max_difference(gpu[k], cpu[k]), 1e-13) << rows << " " << k;
  for (int64_t offset : {0, 1}) {  // float4 kernels, then the scalar ones
    const std::vector<at::Tensor> single = mix_on({in[0], in[1], in[2]}, in[3], at::kCUDA, at::kFloat, offset);
    for (size_t k = 0; k < cpu.size(); ++k)
      EXPECT_LT(max_difference(single[k], cpu[k]), 2e-5 * cpu[k].abs().max().item<double>())
          << rows << " offset " << offset << " " << k;
  }
}

// The merge and its gradients on `device` in `dtype`, as float64 CPU.
std::vector<at::Tensor> merge_on(const at::Tensor& first, const at::Tensor& second, const at::Tensor& weights,
                                 const MergeOrder& order, at::Device device, at::ScalarType dtype,
                                 bool transposed = false) {
  const auto placed = [&](const at::Tensor& t) {
    return (transposed ? t.t().contiguous().t() : t).to(device, dtype).requires_grad_(true);
  };
  const at::Tensor a = placed(first), b = placed(second);
  if (transposed && a.size(0) > 1 && a.size(1) > 1) EXPECT_EQ(a.stride(1), a.size(0)) << "not a transposed view";
  const at::Tensor out = feature_fusion::merge_rows(a, b, order.to(device));
  const auto grads = torch::autograd::grad({(out * weights.to(device, dtype)).sum()}, {a, b}, {}, false, false, true);
  return {out.detach().to(at::kCPU, at::kDouble), grads[0].to(at::kCPU, at::kDouble),
          grads[1].defined() ? grads[1].to(at::kCPU, at::kDouble) : at::zeros({0, first.size(1)}, at::kDouble)};
}

// `transposed`: the sources as transposed views (column stride = their row count), as the planes' samples come.
void expect_merge_parity(int64_t rows, int64_t first_rows, int64_t columns, bool transposed = false) {
  at::Generator g = at::detail::createCPUGenerator(11);
  const at::Tensor points = at::randperm(rows, g, at::TensorOptions().dtype(at::kLong));
  const MergeOrder order =
      MergeOrder::of(points.narrow(0, 0, first_rows), points.narrow(0, first_rows, rows - first_rows));
  const std::vector<at::Tensor> first = random_rows(first_rows, columns, 1, 12);
  const std::vector<at::Tensor> rest = random_rows(rows - first_rows, columns, 1, 13);
  const std::vector<at::Tensor> weights = random_rows(rows, columns, 1, 14);
  const auto cpu = merge_on(first[0], rest[0], weights[0], order, at::kCPU, at::kDouble);
  for (at::ScalarType dtype : {at::kDouble, at::kFloat}) {
    const auto gpu = merge_on(first[0], rest[0], weights[0], order, at::kCUDA, dtype, transposed);
    // A move of values: exact in float64, float32's rounding of the inputs otherwise.
    const double tolerance = dtype == at::kDouble ? 0.0 : 1e-5;
    for (size_t k = 0; k < cpu.size(); ++k)
      EXPECT_LE(max_difference(gpu[k], cpu[k]), tolerance) << rows << " x " << columns << " " << dtype << " " << k;
  }
}

TEST(FeatureFusionCuda, GatedMixMatchesTheCpuBackend) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_mix_parity(215782, 96);
  expect_mix_parity(33, 7);
}

TEST(FeatureFusionCuda, MergeRowsMatchesTheCpuBackend) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_merge_parity(215782, 213000, 96);                       // the default avatar's body and face points
  expect_merge_parity(1001, 500, 7);                             // rows of no multiple of four: the scalar gather
  expect_merge_parity(64, 64, 32);                               // an empty second subset
  expect_merge_parity(215782, 146000, 96, /*transposed=*/true);  // the planes' samples: the tiled gather
  expect_merge_parity(1001, 500, 7, /*transposed=*/true);
}

// torch.ops reaches the merge without MergeOrder's checks: a source index out of range gives a NaN row on every
// gather path (float4 rows, scalar rows, transposed tiles), never a read out of bounds.
TEST(FeatureFusionCudaSanitizer, ASourceOutOfRangeGivesANanRowOnEveryPath) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  for (const auto& [columns, transposed] : std::vector<std::pair<int64_t, bool>>{{8, false}, {7, false}, {35, true}}) {
    const at::Tensor points = at::arange(40, at::TensorOptions().dtype(at::kLong));
    const MergeOrder order = MergeOrder::of(points.narrow(0, 0, 25), points.narrow(0, 25, 15)).to(at::kCUDA);
    const at::Tensor cpu_first = at::randn({25, columns}), cpu_second = at::randn({15, columns});
    const auto on_gpu = [&](const at::Tensor& t) {
      return transposed ? t.t().contiguous().to(at::kCUDA).t() : t.to(at::kCUDA);
    };
    at::Tensor source = order.source.clone();
    source[3] = 40;
    source[30] = -5;
    const auto op = c10::Dispatcher::singleton().findSchemaOrThrow("sfgs::merge_rows", "");
    std::vector<c10::IValue> stack{on_gpu(cpu_first), on_gpu(cpu_second), source, order.inverse};
    op.callBoxed(&stack);
    const at::Tensor merged = stack[0].toTensor().cpu();
    const at::Tensor expected = at::cat({cpu_first, cpu_second});
    for (int64_t row = 0; row < 40; ++row) {
      if (row == 3 || row == 30)
        EXPECT_TRUE(merged[row].isnan().all().item<bool>()) << columns << " " << row;
      else
        EXPECT_TRUE(at::equal(merged[row], expected[row])) << columns << " " << row;
    }
  }
}

TEST(FeatureFusionCudaSanitizer, SmallCases) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_mix_parity(5, 8);
  expect_mix_parity(3, 3);
  expect_merge_parity(12, 5, 8);
  expect_merge_parity(12, 7, 3);
  expect_merge_parity(40, 25, 35, /*transposed=*/true);
}

}  // namespace
}  // namespace sfgs::testing
