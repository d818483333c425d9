// PSNR, SSIM and mask IoU with ATen operations only, so autograd differentiates them and they run on any device.
#include "metrics/image_metrics.h"

#include <array>
#include <cmath>
#include <sstream>
#include <vector>

#include <ATen/ATen.h>

#include "common/constants.h"
#include "metrics/image_layout.h"
#include "ops/ssim/ssim_math.h"
#include "metrics/constants.h"
#include "ops/ssim/constants.h"

namespace sfgs::metrics {
namespace {

constexpr int64_t kMaxImageChannels = 4;  // grey, RGB, RGBA: a wider last dimension is a channels-first batch

}  // namespace

namespace detail {

void check_image_pair(const char* metric, const at::Tensor& prediction, const at::Tensor& target, int64_t channels) {
  for (const auto* image : {&prediction, &target}) {
    const char* name = image == &prediction ? "prediction" : "target";
    TORCH_CHECK(image->defined() && (image->dim() == 3 || image->dim() == 4), metric, ": ", name,
                " must be an image (H, W, C) or a batch (B, H, W, C), got ", describe(*image));
    TORCH_CHECK(at::isFloatingType(image->scalar_type()), metric, ": ", name,
                " must be a floating tensor with values in [0, 1], got ", describe(*image));
    TORCH_CHECK(image->numel() > 0, metric, ": ", name, " must not be empty, got ", describe(*image));
  }
  TORCH_CHECK(prediction.sizes() == target.sizes(), metric, ": prediction and target must have the same shape, got ",
              describe(prediction), " and ", describe(target));
  TORCH_CHECK(prediction.scalar_type() == target.scalar_type() && prediction.device() == target.device(), metric,
              ": prediction and target must share dtype and device, got ", describe(prediction), " and ",
              describe(target));
  const bool channels_first = prediction.size(prediction.dim() - 3) == channels;
  TORCH_CHECK(channels <= 0 || prediction.size(-1) == channels, metric, ": images must have ", channels,
              " channels (last dimension: channels-last (H, W, C) or (B, H, W, C)), got ", describe(prediction),
              !channels_first         ? ""
              : prediction.dim() == 4 ? "; a (B, C, H, W) batch takes .permute(0, 2, 3, 1)"
                                      : "; a (C, H, W) image takes .permute(1, 2, 0)");
  // Channels last: a (B, C, H, W) batch would be read as images C rows high with W channels.
  TORCH_CHECK(prediction.size(-1) <= kMaxImageChannels, metric,
              ": images must be channels-last (H, W, C) or (B, H, W, C) with at most ", kMaxImageChannels,
              " channels, got ", describe(prediction), "; a (B, C, H, W) batch takes .permute(0, 2, 3, 1)");
}

at::Tensor to_batch_nchw(const at::Tensor& image) {
  const at::Tensor batch = image.dim() == 3 ? image.unsqueeze(0) : image;
  return batch.permute({0, 3, 1, 2}).contiguous();
}

at::Tensor match_batch_layout(const at::Tensor& per_image, const at::Tensor& image) {
  return image.dim() == 3 ? per_image.squeeze(0) : per_image;
}

}  // namespace detail

namespace {

// The separable Gaussian filter of every channel, without padding (each output needs a full window). Autograd
// records a grouped conv2d cheaply. Without gradients, eleven in-place multiply-adds per direction are faster
// on the CPU: 1.5x in float32, 8x in float64 (which has no fast convolution), so evaluation can afford float64.
at::Tensor filter_valid(const at::Tensor& x) {
  const std::array<double, kSsimWindowSize> taps = ssim::gaussian_window();
  const int64_t channels = x.size(1);
  const int64_t height = x.size(2) - (kSsimWindowSize - 1), width = x.size(3) - (kSsimWindowSize - 1);
  if (x.requires_grad()) {
    const at::Tensor window = at::tensor(at::ArrayRef<double>(taps), at::kDouble).to(x.options());
    const at::Tensor horizontal = window.view({1, 1, 1, kSsimWindowSize}).expand({channels, 1, 1, kSsimWindowSize});
    const at::Tensor vertical = window.view({1, 1, kSsimWindowSize, 1}).expand({channels, 1, kSsimWindowSize, 1});
    // Named arrays: a braced {0, 0} would also match conv2d's string padding overload.
    const std::array<int64_t, 2> unit = {1, 1}, none = {0, 0};
    const at::Tensor rows = at::conv2d(x, horizontal.contiguous(), {}, unit, none, unit, channels);
    return at::conv2d(rows, vertical.contiguous(), {}, unit, none, unit, channels);
  }
  at::Tensor rows = x.narrow(3, 0, width) * taps[0];
  for (int k = 1; k < kSsimWindowSize; ++k) rows.add_(x.narrow(3, k, width), taps[k]);
  at::Tensor filtered = rows.narrow(2, 0, height) * taps[0];
  for (int k = 1; k < kSsimWindowSize; ++k) filtered.add_(rows.narrow(2, k, height), taps[k]);
  return filtered;
}

}  // namespace

at::Tensor psnr(const at::Tensor& prediction, const at::Tensor& target) {
  detail::check_image_pair("psnr", prediction, target);
  const at::Tensor batch_p = prediction.dim() == 3 ? prediction.unsqueeze(0) : prediction;
  const at::Tensor batch_t = target.dim() == 3 ? target.unsqueeze(0) : target;
  const at::Tensor mse = (batch_p - batch_t).pow(2).mean({1, 2, 3});
  const at::Tensor value = 10.0 * at::log10(kImageDataRange * kImageDataRange / mse);
  return detail::match_batch_layout(value, prediction);
}

at::Tensor ssim(const at::Tensor& prediction, const at::Tensor& target, SsimBorder border) {
  const at::Tensor map = ssim_map(prediction, target, border);
  return map.mean({-2, -1});
}

at::Tensor ssim_map(const at::Tensor& prediction, const at::Tensor& target, SsimBorder border) {
  detail::check_image_pair("ssim", prediction, target);
  const int64_t height = prediction.size(-3), width = prediction.size(-2);
  const int radius = kSsimWindowSize / 2;
  if (border == SsimBorder::valid) {
    TORCH_CHECK(height >= kSsimWindowSize && width >= kSsimWindowSize,
                "ssim: the valid border mode needs images of at least ", kSsimWindowSize, " x ", kSsimWindowSize,
                " pixels, got ", describe(prediction));
  } else if (border == SsimBorder::reflect) {
    TORCH_CHECK(height > radius && width > radius, "ssim: the reflect border mode needs images larger than ", radius,
                " x ", radius, " pixels, got ", describe(prediction));
  }

  // Padding the images first and then forming the products equals padding every moment map, for both zero
  // and reflect padding; the filter itself then never pads.
  const auto pad = [&](const at::Tensor& x) {
    switch (border) {
      case SsimBorder::zero:
        return at::constant_pad_nd(x, {radius, radius, radius, radius}, 0.0);
      case SsimBorder::reflect:
        return at::reflection_pad2d(x, {radius, radius, radius, radius});
      case SsimBorder::valid:
        break;
    }
    return x;
  };
  const at::Tensor x = pad(detail::to_batch_nchw(prediction));
  const at::Tensor y = pad(detail::to_batch_nchw(target));
  const int64_t channels = x.size(1);
  // One filter pass over the five moment inputs instead of five.
  const at::Tensor moments = filter_valid(at::cat({x, y, x * x, y * y, x * y}, 1));
  const std::vector<at::Tensor> m = moments.split(channels, 1);
  const at::Tensor mu_x2 = m[0] * m[0], mu_y2 = m[1] * m[1], mu_xy = m[0] * m[1];
  at::Tensor var_x = m[2] - mu_x2, var_y = m[3] - mu_y2;
  const at::Tensor cov_xy = m[4] - mu_xy;
  if (border == SsimBorder::reflect) {
    // torchmetrics clamps the variances that cancellation made slightly negative; the other references don't.
    var_x = var_x.clamp_min(0.0);
    var_y = var_y.clamp_min(0.0);
  }
  const double c1 = std::pow(kSsimK1 * kImageDataRange, 2), c2 = std::pow(kSsimK2 * kImageDataRange, 2);
  const at::Tensor map = (2.0 * mu_xy + c1) * (2.0 * cov_xy + c2) / ((mu_x2 + mu_y2 + c1) * (var_x + var_y + c2));
  const at::Tensor per_pixel = map.mean(1);  // (B, H', W')
  return prediction.dim() == 3 ? per_pixel.squeeze(0) : per_pixel;
}

at::Tensor mask_iou(const at::Tensor& mask_a, const at::Tensor& mask_b) {
  for (const auto* mask : {&mask_a, &mask_b}) {
    TORCH_CHECK(mask->defined() && (mask->dim() == 2 || mask->dim() == 3) &&
                    (mask->scalar_type() == at::kBool || at::isFloatingType(mask->scalar_type())),
                "mask_iou: masks must be bool or floating tensors of shape (H, W) or (B, H, W), got ", describe(*mask));
  }
  TORCH_CHECK(mask_a.sizes() == mask_b.sizes() && mask_a.device() == mask_b.device(),
              "mask_iou: masks must have the same shape and device, got ", describe(mask_a), " and ", describe(mask_b));
  const auto binary = [](const at::Tensor& m) {
    const at::Tensor b = m.scalar_type() == at::kBool ? m : m > kMaskInsideThreshold;
    return (m.dim() == 2 ? b.unsqueeze(0) : b).flatten(1);
  };
  const at::Tensor a = binary(mask_a), b = binary(mask_b);
  const at::Tensor intersection = at::logical_and(a, b).sum(1).to(at::kDouble);
  const at::Tensor union_count = at::logical_or(a, b).sum(1).to(at::kDouble);
  const at::Tensor iou =
      at::where(union_count > 0, intersection / union_count.clamp_min(1.0), at::ones_like(union_count));
  return mask_a.dim() == 2 ? iou.squeeze(0) : iou;
}

}  // namespace sfgs::metrics
