// PSNR, SSIM and mask IoU without files: closed forms, an independent loop-based SSIM for each border mode,
// finite-difference gradients in float64, and the errors for bad inputs.
#include <cmath>
#include <functional>
#include <string>

#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "metrics/image_metrics.h"
#include "test_metrics_support.h"

namespace sfgs::testing {
namespace {

using metrics::SsimBorder;

constexpr SsimBorder kBorders[] = {SsimBorder::valid, SsimBorder::zero, SsimBorder::reflect};

at::Tensor random_channels(int64_t h, int64_t w, int64_t c, uint64_t seed) {
  at::manual_seed(seed);
  return at::rand({h, w, c}, at::kDouble);
}

// SSIM straight from its definition with explicit loops: every window sample fetched through the border rule.
double loop_ssim(const at::Tensor& x_in, const at::Tensor& y_in, SsimBorder border) {
  const at::Tensor xc = x_in.contiguous(), yc = y_in.contiguous();
  const int64_t h = xc.size(0), w = xc.size(1), c = xc.size(2);
  const double* x = xc.data_ptr<double>();
  const double* y = yc.data_ptr<double>();
  double g[11], g_sum = 0;
  for (int i = 0; i < 11; ++i) g_sum += g[i] = std::exp(-(i - 5.0) * (i - 5.0) / 4.5);
  for (double& v : g) v /= g_sum;
  const auto sample = [&](const double* img, int64_t i, int64_t j, int64_t k) {
    if (border == SsimBorder::reflect) {
      i = i < 0 ? -i : (i >= h ? 2 * (h - 1) - i : i);
      j = j < 0 ? -j : (j >= w ? 2 * (w - 1) - j : j);
    }
    if (i < 0 || i >= h || j < 0 || j >= w) return 0.0;  // zero padding (never reached in valid mode)
    return img[(i * w + j) * c + k];
  };
  const int64_t margin = border == SsimBorder::valid ? 5 : 0;
  double total = 0;
  int64_t count = 0;
  for (int64_t i = margin; i < h - margin; ++i)
    for (int64_t j = margin; j < w - margin; ++j)
      for (int64_t k = 0; k < c; ++k) {
        double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
        for (int a = 0; a < 11; ++a)
          for (int b = 0; b < 11; ++b) {
            const double weight = g[a] * g[b];
            const double xv = sample(x, i + a - 5, j + b - 5, k), yv = sample(y, i + a - 5, j + b - 5, k);
            mx += weight * xv;
            my += weight * yv;
            sxx += weight * xv * xv;
            syy += weight * yv * yv;
            sxy += weight * xv * yv;
          }
        double vx = sxx - mx * mx, vy = syy - my * my;
        if (border == SsimBorder::reflect) {
          vx = std::max(vx, 0.0);
          vy = std::max(vy, 0.0);
        }
        const double c1 = 1e-4, c2 = 9e-4;
        total += (2 * mx * my + c1) * (2 * (sxy - mx * my) + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2));
        ++count;
      }
  return total / double(count);
}

// Checks the autograd gradient of f at x against central differences along random directions (float64).
void expect_gradient_matches(const std::function<at::Tensor(const at::Tensor&)>& f, const at::Tensor& x,
                             const std::string& label) {
  const at::Tensor probe = x.detach().clone().requires_grad_(true);
  const at::Tensor gradient = torch::autograd::grad({f(probe)}, {probe})[0];
  for (uint64_t seed = 0; seed < 4; ++seed) {
    at::manual_seed(100 + seed);
    const at::Tensor direction = at::randn_like(x);
    const double step = 1e-6;
    const double numeric =
        (f(x + step * direction).item<double>() - f(x - step * direction).item<double>()) / (2 * step);
    const double analytic = (gradient * direction).sum().item<double>();
    EXPECT_NEAR(analytic, numeric, 1e-7 * std::abs(numeric) + 1e-10) << label << ", direction " << seed;
  }
}

TEST(MetricsPsnr, IdenticalImagesGivePositiveInfinity) {
  const at::Tensor x = random_channels(8, 9, 3, 1);
  const double value = metrics::psnr(x, x.clone()).item<double>();
  EXPECT_TRUE(std::isinf(value) && value > 0) << value;
}

TEST(MetricsPsnr, KnownNoiseLevel) {
  // +-delta with random signs: the MSE is exactly delta^2 whatever the pattern.
  const at::Tensor x = random_channels(16, 20, 3, 2) * 0.8 + 0.1;
  at::manual_seed(3);
  const at::Tensor signs = at::where(at::rand_like(x) < 0.5, -at::ones_like(x), at::ones_like(x));
  const double deltas[] = {0.05, 0.01};
  const at::Tensor batch_a = at::stack({x, x});
  const at::Tensor batch_b = at::stack({x + deltas[0] * signs, x + deltas[1] * signs});
  const at::Tensor values = metrics::psnr(batch_b, batch_a);
  ASSERT_EQ(values.sizes(), at::IntArrayRef({2}));
  EXPECT_NEAR(values[0].item<double>(), -20.0 * std::log10(0.05), 1e-10);  // 26.0206 dB
  EXPECT_NEAR(values[1].item<double>(), 40.0, 1e-10);
  EXPECT_EQ(metrics::psnr(x + deltas[0] * signs, x).dim(), 0) << "an unbatched image gives a 0-dim result";
}

TEST(MetricsSsim, IdenticalImagesGiveOneInEveryMode) {
  const at::Tensor x = random_channels(14, 15, 3, 4);
  for (SsimBorder border : kBorders) EXPECT_NEAR(metrics::ssim(x, x, border).item<double>(), 1.0, 1e-12);
}

TEST(MetricsSsim, ConstantImagesMatchTheClosedForm) {
  // Constant 0.3 against constant 0.5: no variance, so SSIM = (2 mu_x mu_y + C1) / (mu_x^2 + mu_y^2 + C1).
  const at::Tensor x = at::full({16, 18, 3}, 0.3, at::kDouble), y = at::full({16, 18, 3}, 0.5, at::kDouble);
  const double expected = (2 * 0.3 * 0.5 + 1e-4) / (0.3 * 0.3 + 0.5 * 0.5 + 1e-4);  // 0.3001 / 0.3401
  EXPECT_NEAR(metrics::ssim(x, y, SsimBorder::valid).item<double>(), expected, 1e-12);
  EXPECT_NEAR(metrics::ssim(x, y, SsimBorder::reflect).item<double>(), expected, 1e-12);
  // Zero padding darkens the border windows and invents variance there, which lowers the structure term.
  const double zero = metrics::ssim(x, y, SsimBorder::zero).item<double>();
  EXPECT_LT(zero, expected - 1e-3);
  EXPECT_NEAR(zero, loop_ssim(x, y, SsimBorder::zero), 1e-12);
}

TEST(MetricsSsim, ConstantShiftOfARampMatchesTheHandComputedValue) {
  // x = 0.2 + 0.02 j (a horizontal ramp), y = x + 0.1. In the valid region the symmetric window's mean of a ramp
  // is its centre value, and x, y have identical variance and covariance, so the structure term is exactly 1:
  // SSIM = mean over centre columns j of (2 m (m + s) + C1) / (m^2 + (m + s)^2 + C1), m = 0.2 + 0.02 j.
  const int64_t h = 12, w = 25;
  const at::Tensor ramp = (0.2 + 0.02 * at::arange(w, at::kDouble)).view({1, w, 1}).expand({h, w, 2});
  const double shift = 0.1;
  double expected = 0;
  for (int64_t j = 5; j < w - 5; ++j) {
    const double m = 0.2 + 0.02 * double(j);
    expected += (2 * m * (m + shift) + 1e-4) / (m * m + (m + shift) * (m + shift) + 1e-4);
  }
  expected /= double(w - 10);
  EXPECT_NEAR(metrics::ssim(ramp, ramp + shift, SsimBorder::valid).item<double>(), expected, 1e-12);
}

TEST(MetricsSsim, EachBorderModeMatchesItsLoopDefinition) {
  const at::Tensor x = random_channels(13, 17, 2, 5);
  const at::Tensor y = (x + 0.2 * random_channels(13, 17, 2, 6)).clamp(0, 1);
  for (SsimBorder border : kBorders)
    EXPECT_NEAR(metrics::ssim(x, y, border).item<double>(), loop_ssim(x, y, border), 1e-12) << int(border);
}

TEST(MetricsSsim, BorderModesDifferOnlyByWhatTheyAverage) {
  // The images differ only in a central patch whose windows never reach the border. Every mode then has the
  // same SSIM map values off 1 (at the same interior pixels), so the padded modes agree with each other and
  // the sum of (1 - SSIM) is shared: (1 - valid)(H-10)(W-10) = (1 - full)HW. Valid, averaging fewer pixels,
  // is lower.
  const int64_t h = 30, w = 34;
  const at::Tensor x = random_channels(h, w, 3, 7);
  at::Tensor y = x.clone();
  y.slice(0, 13, 17).slice(1, 15, 19).copy_(random_channels(4, 4, 3, 8));
  const double valid = metrics::ssim(x, y, SsimBorder::valid).item<double>();
  const double zero = metrics::ssim(x, y, SsimBorder::zero).item<double>();
  const double reflect = metrics::ssim(x, y, SsimBorder::reflect).item<double>();
  EXPECT_NEAR(zero, reflect, 1e-14);
  EXPECT_NEAR((1 - valid) * double((h - 10) * (w - 10)), (1 - zero) * double(h * w), 1e-11);
  EXPECT_LT(valid, zero - 1e-3);
}

TEST(MetricsSsim, GradientAndNoGradientFiltersAgree) {
  // With a gradient the filter is a grouped conv2d, without one shifted in-place sums: same value either way.
  const at::Tensor x = random_channels(15, 19, 3, 30), y = random_channels(15, 19, 3, 31);
  for (SsimBorder border : kBorders) {
    for (at::ScalarType dtype : {at::kDouble, at::kFloat}) {
      const at::Tensor a = x.to(dtype), b = y.to(dtype);
      const double plain = metrics::ssim(a, b, border).item<double>();
      const double recorded = metrics::ssim(a.clone().requires_grad_(true), b, border).item<double>();
      EXPECT_NEAR(plain, recorded, dtype == at::kDouble ? 1e-14 : 1e-6) << int(border);
    }
  }
}

TEST(MetricsSsim, FlatImagesAgainstThemselvesScoreOneInFloat64) {
  // Every 8-bit grey level as a constant image: the reflect mode's variance clamp must not pull SSIM below 1
  // (in float32 it does for some levels; the protocol therefore runs in float64).
  const at::Tensor levels = (at::arange(256, at::kDouble) / 255.0).view({256, 1, 1, 1}).expand({256, 16, 16, 3});
  for (SsimBorder border : kBorders) {
    const at::Tensor values = metrics::ssim(levels, levels, border);
    EXPECT_LT((values - 1.0).abs().max().item<double>(), 1e-10) << int(border);
  }
}

TEST(MetricsSsim, ValidModeOnTheSmallestImageUsesOneWindow) {
  const at::Tensor x = random_channels(11, 11, 1, 7), y = random_channels(11, 11, 1, 8);
  EXPECT_NEAR(metrics::ssim(x, y, SsimBorder::valid).item<double>(), loop_ssim(x, y, SsimBorder::valid), 1e-12);
}

TEST(MetricsSsim, BatchedImagesGiveOneValueEach) {
  const at::Tensor a = at::stack({random_channels(12, 13, 3, 9), random_channels(12, 13, 3, 10)});
  const at::Tensor b = at::stack({random_channels(12, 13, 3, 11), a[1]});
  const at::Tensor values = metrics::ssim(a, b, SsimBorder::zero);
  ASSERT_EQ(values.sizes(), at::IntArrayRef({2}));
  EXPECT_NEAR(values[0].item<double>(), metrics::ssim(a[0], b[0], SsimBorder::zero).item<double>(), 1e-14);
  EXPECT_NEAR(values[1].item<double>(), 1.0, 1e-12);
}

TEST(MetricsGradients, SsimAndPsnrMatchFiniteDifferences) {
  const at::Tensor x = random_channels(13, 14, 2, 12);
  const at::Tensor y = (x + 0.3 * (random_channels(13, 14, 2, 13) - 0.5)).clamp(0.05, 0.95);
  for (SsimBorder border : kBorders) {
    const std::string mode = "SSIM mode " + std::to_string(int(border));
    expect_gradient_matches([&](const at::Tensor& p) { return metrics::ssim(p, y, border); }, x,
                            mode + " wrt prediction");
    expect_gradient_matches([&](const at::Tensor& t) { return metrics::ssim(x, t, border); }, y, mode + " wrt target");
  }
  expect_gradient_matches([&](const at::Tensor& p) { return metrics::psnr(p, y); }, x, "PSNR");
}

TEST(MetricsMaskIou, TwoRectangles) {
  at::Tensor a = at::zeros({16, 24}, at::kBool), b = at::zeros({16, 24}, at::kBool);
  a.slice(0, 2, 10).slice(1, 3, 13).fill_(true);  // 8 x 10 = 80
  b.slice(0, 5, 12).slice(1, 8, 20).fill_(true);  // 7 x 12 = 84; overlap rows 5..9, cols 8..12 = 25
  EXPECT_NEAR(metrics::mask_iou(a, b).item<double>(), 25.0 / 139.0, 1e-15);
  EXPECT_NEAR(metrics::mask_iou(a.to(at::kFloat) * 0.9, b.to(at::kDouble)).item<double>(), 25.0 / 139.0, 1e-15)
      << "floating masks are thresholded at 0.5";
  const at::Tensor empty = at::zeros({16, 24}, at::kBool);
  const at::Tensor batch = metrics::mask_iou(at::stack({a, a, empty}), at::stack({b, a, empty}));
  ASSERT_EQ(batch.sizes(), at::IntArrayRef({3}));
  EXPECT_NEAR(batch[0].item<double>(), 25.0 / 139.0, 1e-15);
  EXPECT_EQ(batch[1].item<double>(), 1.0);
  EXPECT_EQ(batch[2].item<double>(), 1.0) << "two empty masks agree";
  EXPECT_EQ(metrics::mask_iou(a, empty).item<double>(), 0.0);
}

TEST(MetricsImageValidation, BadInputsAreClearErrors) {
  const at::Tensor x = random_channels(12, 12, 3, 14);
  expect_error([&] { metrics::psnr(x, random_channels(12, 13, 3, 1)); },
               {"psnr: prediction and target must have the same shape",
                "a Double tensor of shape [12, 12, 3] on cpu and a Double tensor of shape [12, 13, 3]"});
  expect_error([&] { metrics::ssim(x, x.to(at::kFloat), SsimBorder::valid); },
               {"ssim: prediction and target must share dtype"});
  expect_error([&] { metrics::psnr(x.to(at::kByte), x.to(at::kByte)); },
               {"psnr: prediction must be a floating tensor with values in [0, 1], got a Byte tensor"});
  // A channels-first batch (B, C, H, W) is not read as images C rows high with W channels.
  const at::Tensor nchw = x.permute({2, 0, 1}).unsqueeze(0);
  expect_error([&] { metrics::psnr(nchw, nchw.clone()); },
               {"psnr: images must be channels-last (H, W, C) or (B, H, W, C) with at most 4 channels",
                "[1, 3, 12, 12]", ".permute(0, 2, 3, 1)"});
  expect_error(
      [&] { metrics::ssim(x[0], x[0], SsimBorder::zero); },
      {"ssim: prediction must be an image (H, W, C) or a batch (B, H, W, C), got a Double tensor of shape [12, 3]"});
  expect_error([&] { metrics::ssim(x.slice(0, 0, 10), x.slice(0, 0, 10), SsimBorder::valid); },
               {"the valid border mode needs images of at least 11 x 11 pixels", "[10, 12, 3]"});
  expect_error([&] { metrics::ssim(x.slice(1, 0, 5), x.slice(1, 0, 5), SsimBorder::reflect); },
               {"the reflect border mode needs images larger than 5 x 5 pixels"});
  expect_error([&] { metrics::psnr(at::Tensor(), x); }, {"got an undefined tensor"});
  expect_error(
      [&] {
        metrics::mask_iou(at::zeros({4, 4}, at::kBool), at::zeros({4, 5}, at::kBool));
      },
      {"mask_iou: masks must have the same shape"});
  expect_error(
      [&] {
        metrics::mask_iou(at::zeros({4, 4}, at::kInt), at::zeros({4, 4}, at::kInt));
      },
      {"masks must be bool or floating tensors"});
}

}  // namespace
}  // namespace sfgs::testing
