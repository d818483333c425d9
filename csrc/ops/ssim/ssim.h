#pragma once
// sfgs's fused SSIM, the structural term of the training loss (train/losses.h: 1 - SSIM): the mean SSIM of an
// image against its target with zero padding, the value of metrics::ssim(prediction, target, SsimBorder::zero).
// LibTorch composes that of a padded concatenation, two grouped convolutions and a dozen element-wise maps, each a
// pass over five H x W x C moment maps, and autograd walks them back again. Here the forward is one pass (a CPU
// backend and CUDA kernels chosen by the device: the moments filtered in shared-memory tiles, the SSIM map summed per
// tile, no host read) and the backward another, with one autograd node. docs/performance.md ("Fused SSIM").
#include <ATen/core/Tensor.h>

namespace sfgs::ssim {

// prediction and target (H, W, C) of one floating dtype (float32 or float64) and device (CPU or CUDA), values in
// [0, 1]; a 0-dim tensor. Differentiable in the prediction (once: no second derivative); the target is a constant
// image, and a target that requires a gradient is refused (metrics::ssim differentiates both). NaN in either image
// propagates to the value and the gradient, as it does through metrics::ssim.
at::Tensor fused_ssim(const at::Tensor& prediction, const at::Tensor& target);

}  // namespace sfgs::ssim
