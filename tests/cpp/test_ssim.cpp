// The fused SSIM (ops/ssim/ssim.h) on the CPU backend: its value against metrics::ssim with the zero border (random and
// structured images, odd sizes, images smaller than the window, constant images), its gradient against autograd
// through metrics::ssim and against central differences, float32 against float64, and the errors at its boundary.
#include <cmath>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/core/grad_mode.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "metrics/image_metrics.h"
#include "ops/ssim/ssim.h"
#include "test_metrics_support.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using metrics::SsimBorder;
using ssim::fused_ssim;

struct ImagePair {
  at::Tensor prediction, target;
};

// A target and a prediction near it (noise, clamped to [0, 1]), so the SSIM is neither 0 nor 1.
ImagePair noisy_pair(int64_t h, int64_t w, int64_t c, uint64_t seed) {
  at::Generator g = at::detail::createCPUGenerator(seed);
  const at::Tensor target = at::rand({h, w, c}, g, kF64);
  const at::Tensor prediction = (target + 0.2 * (at::rand({h, w, c}, g, kF64) - 0.5)).clamp(0, 1);
  return {prediction, target};
}

// Smooth ramps and a checkerboard: large flat and structured regions rather than noise.
ImagePair structured_pair(int64_t h, int64_t w) {
  const at::Tensor rows = at::arange(h, kF64).view({h, 1, 1}), columns = at::arange(w, kF64).view({1, w, 1});
  const at::Tensor channels = at::arange(3, kF64).view({1, 1, 3});
  const at::Tensor ramp = (rows / h + 0.5 * columns / w + 0.1 * channels).remainder(1.0);
  const at::Tensor checker = ((rows / 4).floor() + (columns / 4).floor()).remainder(2).expand({h, w, 3});
  return {(0.7 * ramp + 0.3 * checker).contiguous(), ramp.contiguous()};
}

double reference_ssim(const ImagePair& p) {
  return metrics::ssim(p.prediction, p.target, SsimBorder::zero).item<double>();
}

// The gradient of `scale` times the mean SSIM in the prediction, by the fused op or by autograd of the reference.
at::Tensor fused_gradient(const ImagePair& p, double scale) {
  const at::Tensor x = p.prediction.clone().requires_grad_(true);
  return torch::autograd::grad({scale * fused_ssim(x, p.target)}, {x})[0];
}

at::Tensor reference_gradient(const ImagePair& p, double scale) {
  const at::Tensor x = p.prediction.clone().requires_grad_(true);
  return torch::autograd::grad({scale * metrics::ssim(x, p.target, SsimBorder::zero)}, {x})[0];
}

TEST(SsimForward, MatchesMetricsSsimWithTheZeroBorder) {
  struct Size {
    int64_t h, w, c;
  };
  // Odd sizes, one pixel, images narrower or shorter than the 11 x 11 window, one and four channels.
  for (const Size s : {Size{40, 33, 3}, Size{13, 17, 3}, Size{1, 1, 3}, Size{5, 7, 3}, Size{3, 60, 3}, Size{64, 2, 1},
                       Size{11, 11, 4}, Size{97, 120, 3}}) {
    const ImagePair p = noisy_pair(s.h, s.w, s.c, uint64_t(s.h * 1000 + s.w));
    const std::string what = std::to_string(s.h) + " x " + std::to_string(s.w) + " x " + std::to_string(s.c);
    const double expected = reference_ssim(p);
    EXPECT_NEAR(fused_ssim(p.prediction, p.target).item<double>(), expected, 1e-12) << what;
    // The recorded path (derivative maps written) gives the same value.
    EXPECT_NEAR(fused_ssim(p.prediction.clone().requires_grad_(true), p.target).item<double>(), expected, 1e-12)
        << what;
  }
  for (const ImagePair& p : {structured_pair(37, 53), structured_pair(8, 200)})
    EXPECT_NEAR(fused_ssim(p.prediction, p.target).item<double>(), reference_ssim(p), 1e-12);
}

TEST(SsimForward, ConstantImages) {
  const at::Tensor grey = at::full({19, 23, 3}, 0.4, kF64), light = at::full({19, 23, 3}, 0.7, kF64);
  EXPECT_NEAR(fused_ssim(grey, grey).item<double>(), 1.0, 1e-14) << "an image against itself";
  // Against another constant the zero border makes the moments vary near the edges: still the reference's value.
  EXPECT_NEAR(fused_ssim(grey, light).item<double>(), reference_ssim({grey, light}), 1e-12);
  EXPECT_NEAR(fused_ssim(at::zeros_like(grey), at::zeros_like(grey)).item<double>(), 1.0, 1e-14) << "black";
}

TEST(SsimForward, TakesViewsAndRecordsOnlyWhenAsked) {
  const ImagePair p = noisy_pair(21, 18, 3, 5);
  // A transposed (non-contiguous) view is read as the image it shows.
  const at::Tensor x = p.prediction.transpose(0, 1), y = p.target.transpose(0, 1);
  EXPECT_NEAR(fused_ssim(x, y).item<double>(), metrics::ssim(x, y, SsimBorder::zero).item<double>(), 1e-12);
  EXPECT_FALSE(fused_ssim(p.prediction, p.target).requires_grad());
  const at::Tensor leaf = p.prediction.clone().requires_grad_(true);
  EXPECT_TRUE(fused_ssim(leaf, p.target).requires_grad());
  const at::NoGradGuard no_grad;
  EXPECT_FALSE(fused_ssim(leaf, p.target).requires_grad());
}

TEST(SsimGradient, MatchesAutogradOfTheReference) {
  struct Case {
    ImagePair images;
    double scale;  // the gradient reaching the mean SSIM
  };
  for (const Case& c :
       {Case{noisy_pair(23, 37, 3, 1), 1.0}, Case{noisy_pair(6, 9, 2, 2), -2.5}, Case{noisy_pair(40, 52, 3, 3), 0.75},
        Case{structured_pair(30, 41), 1.0}, Case{noisy_pair(1, 12, 3, 4), 1.0}}) {
    const at::Tensor expected = reference_gradient(c.images, c.scale);
    const at::Tensor fused = fused_gradient(c.images, c.scale);
    ASSERT_EQ(fused.sizes(), expected.sizes());
    EXPECT_LT(max_difference(fused, expected), 1e-12 * expected.abs().max().item<double>())
        << "image " << c.images.prediction.sizes();
  }
}

TEST(SsimGradient, MatchesCentralDifferences) {
  const ImagePair p = noisy_pair(5, 6, 2, 8);
  const at::Tensor analytic = fused_gradient(p, 1.0);
  const double step = 1e-6;
  at::Tensor x = p.prediction.clone();
  double* values = x.data_ptr<double>();
  for (int64_t i = 0; i < x.numel(); ++i) {
    const double kept = values[i];
    values[i] = kept + step;
    const double above = fused_ssim(x, p.target).item<double>();
    values[i] = kept - step;
    const double below = fused_ssim(x, p.target).item<double>();
    values[i] = kept;
    EXPECT_NEAR(analytic.view(-1)[i].item<double>(), (above - below) / (2 * step), 1e-8) << "value " << i;
  }
}

TEST(SsimPrecision, Float32MatchesFloat64) {
  const ImagePair exact = noisy_pair(120, 97, 3, 11);
  const ImagePair single{exact.prediction.to(at::kFloat), exact.target.to(at::kFloat)};
  const at::Tensor value = fused_ssim(single.prediction, single.target);
  EXPECT_EQ(value.scalar_type(), at::kFloat);
  EXPECT_NEAR(value.item<double>(), fused_ssim(exact.prediction, exact.target).item<double>(), 1e-6);
  const at::Tensor expected = fused_gradient(exact, 1.0);
  const at::Tensor gradient = fused_gradient(single, 1.0);
  EXPECT_EQ(gradient.scalar_type(), at::kFloat);
  EXPECT_LT(max_difference(gradient.to(at::kDouble), expected), 2e-5 * expected.abs().max().item<double>());
}

// NaN is not looked for (that would read the device): it reaches the value and the gradient as through metrics::ssim.
TEST(SsimValidation, NanPropagatesLikeMetricsSsim) {
  ImagePair p = noisy_pair(30, 31, 3, 12);
  p.prediction[15][3][1] = std::nan("");
  EXPECT_TRUE(std::isnan(fused_ssim(p.prediction, p.target).item<double>()));
  EXPECT_TRUE(std::isnan(reference_ssim(p)));
  const at::Tensor fused = fused_gradient(p, 1.0), expected = reference_gradient(p, 1.0);
  EXPECT_TRUE(at::equal(fused.isnan(), expected.isnan())) << "the same pixels are NaN";
  const at::Tensor finite = expected.isfinite();
  EXPECT_LT(max_difference(fused.masked_select(finite), expected.masked_select(finite)),
            1e-12 * expected.masked_select(finite).abs().max().item<double>());
}

TEST(SsimValidation, BadInputsAreClearErrors) {
  const ImagePair p = noisy_pair(12, 12, 3, 14);
  expect_error([&] { fused_ssim(p.prediction, p.target.narrow(1, 0, 11)); },
               {"fused_ssim: prediction and target must have the same shape",
                "a Double tensor of shape [12, 12, 3] on cpu and a Double tensor of shape [12, 11, 3]"});
  expect_error([&] { fused_ssim(p.prediction, p.target.to(at::kFloat)); },
               {"fused_ssim: prediction and target must share dtype and device"});
  expect_error([&] { fused_ssim(p.prediction[0], p.target[0]); },
               {"fused_ssim: prediction must be a float32 or float64 image (H, W, C), got a Double tensor of shape "
                "[12, 3]"});
  expect_error([&] { fused_ssim(p.prediction.unsqueeze(0), p.target.unsqueeze(0)); },
               {"fused_ssim: prediction must be a float32 or float64 image (H, W, C)", "[1, 12, 12, 3]"});
  expect_error([&] { fused_ssim(p.prediction.to(at::kHalf), p.target.to(at::kHalf)); },
               {"fused_ssim: prediction must be a float32 or float64 image", "Half"});
  expect_error([&] { fused_ssim(p.prediction, p.target.to(at::kByte)); },
               {"fused_ssim: target must be a float32 or float64 image", "Byte"});
  const at::Tensor empty = at::empty({0, 4, 3}, kF64);
  expect_error([&] { fused_ssim(empty, empty); }, {"fused_ssim: prediction must not be empty"});
  expect_error([&] { fused_ssim(at::Tensor(), p.target); },
               {"fused_ssim: prediction must be a float32 or float64 image", "an undefined tensor"});
  expect_error([&] { fused_ssim(p.prediction, p.target.clone().requires_grad_(true)); },
               {"fused_ssim: the target must not require a gradient", "use metrics::ssim for both"});
  const at::Tensor meta = at::empty({4, 4, 3}, at::TensorOptions(at::kMeta).dtype(at::kDouble));
  expect_error([&] { fused_ssim(meta, p.target); }, {"fused_ssim: prediction must be on the CPU or a CUDA device"});
}

TEST(SsimOp, IsADispatcherOpWhoseMetaKernelsDescribeItsOutputs) {
  expect_backend_kernels("sfgs::fused_ssim", true);
  expect_backend_kernels("sfgs::fused_ssim_with_derivatives", false);
  expect_backend_kernels("sfgs::fused_ssim_backward", false);
  const ImagePair p = noisy_pair(13, 17, 2, 8);
  expect_meta_describes_cpu("sfgs::fused_ssim", {p.prediction, p.target});
  const std::vector<c10::IValue> forward =
      call_boxed(registered_op("sfgs::fused_ssim_with_derivatives"), {p.prediction, p.target});
  expect_meta_describes_cpu("sfgs::fused_ssim_with_derivatives", {p.prediction, p.target});
  expect_meta_describes_cpu("sfgs::fused_ssim_backward",
                            {at::ones({}, kF64), p.prediction, p.target, forward[1].toTensor()});
  EXPECT_TRUE(at::equal(forward[0].toTensor(), ssim::fused_ssim(p.prediction, p.target)));
  EXPECT_THROW(call_boxed(registered_op("sfgs::fused_ssim_backward"),
                          {at::ones({}, kF64), p.prediction, p.target, forward[1].toTensor().narrow(1, 0, 1)}),
               c10::Error);
}

}  // namespace
}  // namespace sfgs::testing
