#pragma once
// Full-reference image metrics on values in [0, 1] (data range 1): PSNR, SSIM in three border conventions and
// mask IoU. Images are channels-last like the splatting op's output: (H, W, C) gives a 0-dim result, a batch
// (B, H, W, C) gives one value per image, shape (B). Differentiable through autograd. See docs/metrics.md.
#include <ATen/core/Tensor.h>

namespace sfgs::metrics {

// 10 log10(1 / MSE), the MSE taken over all H x W x C values of one image. Identical images give +inf (as
// torchmetrics does); the caller decides how to report it.
at::Tensor psnr(const at::Tensor& prediction, const at::Tensor& target);

// Where SSIM's 11 x 11 Gaussian window may reach and which pixels are averaged.
enum class SsimBorder {
  // No padding; the mean runs over the (H-10) x (W-10) pixels whose window fits. Equals scikit-image
  // (gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1), pytorch-msssim
  // (data_range=1) and torchmetrics <= 1.4.1.
  valid,
  // Zero padding of 5 px, mean over all H x W pixels: the 3DGS / ExAvatar training loss.
  zero,
  // Reflect padding of 5 px (edge pixel not repeated), variances clamped at 0, mean over all H x W pixels:
  // torchmetrics >= 1.4.2, the number ExAvatar-style papers report.
  reflect,
};

// Mean SSIM per image: computed per channel (no luminance conversion) and averaged over channels and pixels.
at::Tensor ssim(const at::Tensor& prediction, const at::Tensor& target, SsimBorder border);

// The per-pixel SSIM map that `ssim` averages, itself averaged over channels: (H, W) for one image, (B, H, W) for a
// batch, where the valid border leaves (H - 10) x (W - 10) pixels (each the centre of a window that fits).
at::Tensor ssim_map(const at::Tensor& prediction, const at::Tensor& target, SsimBorder border);

// |A and B| / |A or B| of two (H, W) or batched (B, H, W) masks; bool masks as they are, floating masks
// thresholded at 0.5. Two empty masks agree perfectly: IoU 1. Not differentiable.
at::Tensor mask_iou(const at::Tensor& mask_a, const at::Tensor& mask_b);

}  // namespace sfgs::metrics
