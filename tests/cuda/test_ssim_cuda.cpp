// The fused SSIM's CUDA kernels (ops/ssim/ssim.h) against its CPU backend: float64 parity of the value and the
// prediction's gradient at the training size (800 x 1200) and at sizes that are not multiples of the tiles, float32
// at 800 x 1200 against float64, the device check at the boundary, and a small case for compute-sanitizer. Skips
// without a CUDA device.
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "ops/ssim/ssim.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using ssim::fused_ssim;

struct Result {
  double value;
  at::Tensor gradient;  // of the mean SSIM in the prediction, float64 on the CPU
};

// The op on `device` in `dtype`, from the same float64 CPU draws: a target and a prediction near it.
Result run_on(at::Device device, at::ScalarType dtype, int64_t h, int64_t w, int64_t c, uint64_t seed) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor target = at::rand({h, w, c}, g, f64);
  const at::Tensor prediction = (target + 0.2 * (at::rand({h, w, c}, g, f64) - 0.5)).clamp(0, 1);
  const at::Tensor x = prediction.to(device, dtype).requires_grad_(true);
  const at::Tensor value = fused_ssim(x, target.to(device, dtype));
  const at::Tensor gradient = torch::autograd::grad({value}, {x})[0];
  return {value.item<double>(), gradient.to(at::kCPU, at::kDouble)};
}

void expect_parity(int64_t h, int64_t w, int64_t c) {
  const Result cpu = run_on(at::kCPU, at::kDouble, h, w, c, 3);
  const Result gpu = run_on(at::kCUDA, at::kDouble, h, w, c, 3);
  const std::string what = std::to_string(h) + " x " + std::to_string(w) + " x " + std::to_string(c);
  EXPECT_NEAR(gpu.value, cpu.value, 1e-12) << what;
  // The gradient of a mean is of order 1 / N: compared relative to its largest value.
  EXPECT_LT(max_difference(gpu.gradient, cpu.gradient), 1e-11 * cpu.gradient.abs().max().item<double>()) << what;
}

TEST(SsimCuda, MatchesTheCpuBackendInFloat64) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  // The training size; sizes off the 32-column and 8-row (float64) tiles; images smaller than a tile or the window;
  // one and four channels.
  struct Size {
    int64_t h, w, c;
  };
  for (const Size s : {Size{800, 1200, 3}, Size{540, 960, 3}, Size{37, 45, 3}, Size{16, 32, 3}, Size{17, 33, 3},
                       Size{5, 3, 3}, Size{1, 1, 3}, Size{33, 65, 1}, Size{9, 70, 4}})
    expect_parity(s.h, s.w, s.c);
}

// The training loss's precision: float32 against float64 at 800 x 1200.
TEST(SsimCuda, Float32AtTheTrainingSize) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const Result exact = run_on(at::kCUDA, at::kDouble, 800, 1200, 3, 9);
  const Result single = run_on(at::kCUDA, at::kFloat, 800, 1200, 3, 9);
  EXPECT_NEAR(single.value, exact.value, 1e-6);
  EXPECT_LT(max_difference(single.gradient, exact.gradient), 2e-5 * exact.gradient.abs().max().item<double>());
}

TEST(SsimCuda, ImagesOnTwoDevicesAreAClearError) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const at::Tensor image = at::rand({8, 8, 3});
  try {
    fused_ssim(image.to(at::kCUDA), image);
    ADD_FAILURE() << "expected an error";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what_without_backtrace()).find("prediction and target must share dtype and device"),
              std::string::npos)
        << e.what_without_backtrace();
  }
}

// Small enough for compute-sanitizer: both dtypes, an image smaller than a tile with a partial last tile.
TEST(SsimCudaSanitizer, SmallImage) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  for (const at::ScalarType dtype : {at::kFloat, at::kDouble}) {
    const Result cpu = run_on(at::kCPU, dtype, 13, 37, 3, 5);
    const Result gpu = run_on(at::kCUDA, dtype, 13, 37, 3, 5);
    const double tolerance = dtype == at::kDouble ? 1e-12 : 2e-5;
    EXPECT_NEAR(gpu.value, cpu.value, tolerance);
    EXPECT_LT(max_difference(gpu.gradient, cpu.gradient), tolerance * cpu.gradient.abs().max().item<double>());
  }
}

}  // namespace
}  // namespace sfgs::testing
