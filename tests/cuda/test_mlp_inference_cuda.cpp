// The fused MLP inference kernel (ops/mlp_inference/mlp_inference.h) against its float64 reference: the avatar's shapes
// (heads: one block of 96 columns; colour offset: two blocks of weight column slices over a base), one to three
// hidden layers, one to eight outputs, row counts off the 16-row tile, no rows, a NaN row that stays its own, and
// recorded in a CUDA graph. Skips without a CUDA device.
#include <algorithm>
#include <limits>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <torch/cuda.h>

#include "mlp_inference_cases.h"

namespace sfgs::testing {
namespace {

constexpr int64_t kWidth = mlp_inference::kFusedWidth;
// Half operands keep 11 significant bits: the outputs' error against float64, relative to their scale.
constexpr double kRelativeTolerance = 1e-2;

const at::TensorOptions kCudaFloat = at::TensorOptions(at::kCUDA).dtype(at::kFloat);

std::vector<at::Tensor> to_cuda(const std::vector<at::Tensor>& inputs) {
  std::vector<at::Tensor> out;
  for (const at::Tensor& t : inputs) out.push_back(t.to(kCudaFloat));
  return out;
}

// The kernel's output against the float64 reference: max error over the outputs' scale.
double relative_error(const at::Tensor& fused, const at::Tensor& expected) {
  const double scale = std::max(1.0, expected.abs().max().item<double>());
  return (fused.to(at::kCPU, at::kDouble) - expected).abs().max().item<double>() / scale;
}

TEST(MlpInferenceCuda, MatchesTheReferenceOnTheAvatarsShapes) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  at::NoGradGuard no_grad;
  at::Generator g = at::detail::createCPUGenerator(11);
  struct Case {
    std::vector<int64_t> widths;
    int layers;
    int64_t outputs, rows;
    bool base;
  };
  for (const Case& c : {Case{{96}, 3, 4, 5003, false}, Case{{96}, 3, 3, 4096, false}, Case{{6, 3}, 3, 3, 777, true},
                        Case{{40, 50, 38}, 2, 8, 33, true}, Case{{1}, 1, 1, 17, false}}) {
    const mlp_inference::Network n = random_network(kWidth, c.widths, c.layers, c.outputs, g);
    const std::vector<at::Tensor> inputs = random_inputs(c.rows, n, g);
    const at::Tensor base = c.base ? at::randn({c.rows, kWidth}, g, at::TensorOptions(at::kDouble)) : at::Tensor();
    const mlp_inference::Network gpu = network_to(n, kCudaFloat);
    ASSERT_TRUE(mlp_inference::fuses(to_cuda(inputs), gpu));
    const at::Tensor fused = mlp_inference::run(to_cuda(inputs), c.base ? base.to(kCudaFloat) : at::Tensor(), gpu);
    const at::Tensor expected = mlp_inference::reference(inputs, base, n);
    ASSERT_EQ(fused.sizes(), expected.sizes());
    EXPECT_LT(relative_error(fused, expected), kRelativeTolerance)
        << c.widths.size() << " blocks, " << c.layers << " layers, " << c.outputs << " outputs, " << c.rows << " rows";
  }
}

TEST(MlpInferenceCuda, ReadsColumnSlicesAndStridedRows) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  at::NoGradGuard no_grad;
  at::Generator g = at::detail::createCPUGenerator(12);
  const mlp_inference::Network whole = random_network(kWidth, {9}, 3, 3, g);
  mlp_inference::Network split = network_to(whole, kCudaFloat);
  const at::Tensor weight = split.input_weights[0];
  split.input_weights = {weight.narrow(1, 0, 6), weight.narrow(1, 6, 3)};  // row stride 9: slices, not copies
  const at::Tensor input = at::randn({301, 9}, g, at::TensorOptions(at::kDouble));
  const at::Tensor on_device = input.to(kCudaFloat);
  const at::Tensor fused =
      mlp_inference::run({on_device.narrow(1, 0, 6), on_device.narrow(1, 6, 3)}, at::Tensor(), split);
  EXPECT_LT(relative_error(fused, mlp_inference::reference({input}, at::Tensor(), whole)), kRelativeTolerance);
}

TEST(MlpInferenceCuda, KeepsANonFiniteRowToItselfAndTakesNoRows) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  at::NoGradGuard no_grad;
  at::Generator g = at::detail::createCPUGenerator(13);
  const mlp_inference::Network n = network_to(random_network(kWidth, {96}, 3, 4, g), kCudaFloat);
  const at::Tensor input = at::randn({40, 96}, g, at::TensorOptions(at::kDouble)).to(kCudaFloat);
  const at::Tensor clean = mlp_inference::run({input}, at::Tensor(), n);
  const at::Tensor poisoned = input.clone();
  poisoned[17][5] = std::numeric_limits<float>::quiet_NaN();
  const at::Tensor out = mlp_inference::run({poisoned}, at::Tensor(), n).cpu();
  EXPECT_TRUE(out[17].isnan().all().item<bool>());
  const at::Tensor others = at::cat({out.narrow(0, 0, 17), out.narrow(0, 18, 22)});
  EXPECT_TRUE(others.equal(at::cat({clean.cpu().narrow(0, 0, 17), clean.cpu().narrow(0, 18, 22)})));

  const at::Tensor none = mlp_inference::run({input.narrow(0, 0, 0)}, at::Tensor(), n);
  EXPECT_EQ(none.sizes(), at::IntArrayRef({0, 4}));
}

TEST(MlpInferenceCuda, ReplaysInACudaGraph) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  at::NoGradGuard no_grad;
  at::Generator g = at::detail::createCPUGenerator(14);
  const mlp_inference::Network n = network_to(random_network(kWidth, {96}, 3, 4, g), kCudaFloat);
  const at::Tensor input = at::randn({1000, 96}, kCudaFloat);
  at::Tensor output;
  const c10::cuda::CUDAStream stream = c10::cuda::getStreamFromPool();
  at::cuda::CUDAGraph graph;
  {
    const c10::cuda::CUDAStreamGuard guard(stream);
    mlp_inference::run({input}, at::Tensor(), n);  // warm-up on the capture stream
    graph.capture_begin();
    output = mlp_inference::run({input}, at::Tensor(), n);
    graph.capture_end();
  }
  for (int k = 0; k < 2; ++k) {
    input.copy_(at::randn({1000, 96}, kCudaFloat));
    graph.replay();
    EXPECT_TRUE(output.equal(mlp_inference::run({input}, at::Tensor(), n))) << "replay " << k;
  }
}

}  // namespace
}  // namespace sfgs::testing
