// The fused pixel-loss op (ops/pixel_loss/pixel_loss.h) on the CPU backend: against its LibTorch composition (the four
// means and the prediction's gradient for any weighting, float64) on images with values beyond [0, 1] (the sRGB
// clamp) and dark ones (CIELAB's linear branch), against central differences, float32 against float64, and the
// errors at its boundary.
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/core/grad_mode.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "ops/pixel_loss/pixel_loss.h"
#include "test_files.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using pixel_loss::pixel_losses;
using pixel_loss::pixel_losses_reference;

// Values in [-0.1, 1.1] (some clamped), a dark corner (the linear branches) and the rest in between.
at::Tensor test_image(int64_t height, int64_t width, at::Generator& g) {
  at::Tensor image = at::rand({height, width, 3}, g, kF64) * 1.2 - 0.1;
  image.narrow(0, 0, height / 2).narrow(1, 0, width / 2).mul_(0.02);
  return image;
}

TEST(PixelLoss, MatchesTheCompositionWithGradients) {
  at::Generator g = at::detail::createCPUGenerator(2);
  for (const auto& [height, width] : {std::pair{2, 2}, std::pair{7, 5}, std::pair{48, 64}}) {
    const at::Tensor prediction = test_image(height, width, g).requires_grad_(true);
    const at::Tensor target = test_image(height, width, g);
    const at::Tensor weights = at::rand({4}, g, kF64) + 0.5;
    const at::Tensor expected = pixel_losses_reference(prediction, target);
    const at::Tensor got = pixel_losses(prediction, target);
    const std::string what = std::to_string(height) + " x " + std::to_string(width);
    EXPECT_LT(max_difference(got, expected), 1e-12) << what;
    const at::Tensor expected_grad = torch::autograd::grad({(expected * weights).sum()}, {prediction})[0];
    const at::Tensor grad = torch::autograd::grad({(got * weights).sum()}, {prediction})[0];
    EXPECT_LT(max_difference(grad, expected_grad), 1e-12) << what;
  }
}

TEST(PixelLoss, GradientsMatchCentralDifferences) {
  at::Generator g = at::detail::createCPUGenerator(6);
  const at::Tensor prediction = (at::rand({3, 4, 3}, g, kF64) * 0.9 + 0.05).requires_grad_(true);
  const at::Tensor target = at::rand({3, 4, 3}, g, kF64);
  const at::Tensor weights = at::rand({4}, g, kF64) + 0.5;
  const auto objective = [&] { return (pixel_losses(prediction, target) * weights).sum(); };
  const at::Tensor analytic = torch::autograd::grad({objective()}, {prediction})[0];
  constexpr double kStep = 1e-7;
  at::NoGradGuard no_grad;
  at::Tensor flat = prediction.detach().view({-1});
  for (int64_t i = 0; i < flat.numel(); ++i) {
    const double kept = flat[i].item<double>();
    flat[i] = kept + kStep;
    const double up = objective().item<double>();
    flat[i] = kept - kStep;
    const double down = objective().item<double>();
    flat[i] = kept;
    EXPECT_NEAR(analytic.view({-1})[i].item<double>(), (up - down) / (2 * kStep), 1e-6) << "value " << i;
  }
}

TEST(PixelLoss, Float32FollowsFloat64) {
  at::Generator g = at::detail::createCPUGenerator(9);
  const at::Tensor prediction = test_image(120, 80, g), target = test_image(120, 80, g);
  const at::Tensor expected = pixel_losses(prediction, target);
  const at::Tensor got = pixel_losses(prediction.to(at::kFloat), target.to(at::kFloat));
  EXPECT_LT(max_difference(got.to(at::kDouble), expected), 1e-6);
}

TEST(PixelLoss, RejectsBadInputs) {
  const at::Tensor image = at::rand({8, 6, 3});
  expect_error_mentioning([&] { pixel_losses(image.narrow(2, 0, 2), image.narrow(2, 0, 2)); }, "(H, W, 3) image");
  expect_error_mentioning([&] { pixel_losses(image.narrow(1, 0, 1), image.narrow(1, 0, 1)); }, "H, W >= 2");
  expect_error_mentioning([&] { pixel_losses(image.to(at::kInt), image.to(at::kInt)); }, "float32 or float64");
  expect_error_mentioning([&] { pixel_losses(image, image.to(at::kDouble)); }, "target must be like the prediction");
  expect_error_mentioning([&] { pixel_losses(image, image.narrow(0, 0, 4)); }, "target must be like the prediction");
  expect_error_mentioning([&] { pixel_losses(image, image.clone().requires_grad_(true)); }, "detach it first");
}

TEST(PixelLoss, IsADispatcherOpWhoseMetaKernelsDescribeItsOutputs) {
  expect_backend_kernels("sfgs::pixel_losses", true);
  expect_backend_kernels("sfgs::pixel_losses_backward", false);
  at::Generator g = at::detail::createCPUGenerator(9);
  const at::Tensor prediction = test_image(7, 9, g), target = test_image(7, 9, g);
  expect_meta_describes_cpu("sfgs::pixel_losses", {prediction, target});
  expect_meta_describes_cpu("sfgs::pixel_losses_backward", {at::rand({4}, kF64), prediction, target});
  EXPECT_TRUE(at::equal(call_boxed(registered_op("sfgs::pixel_losses"), {prediction, target})[0].toTensor(),
                        pixel_loss::pixel_losses(prediction, target)));
  EXPECT_THROW(call_boxed(registered_op("sfgs::pixel_losses_backward"), {at::rand({3}, kF64), prediction, target}),
               c10::Error);
}

}  // namespace
}  // namespace sfgs::testing
