#pragma once
// sfgs's fused per-pixel training losses: the means of |p - t|, of |lab(p) - lab(t)| (CIELAB, train::rgb_to_lab's
// scaling) and of the image gradients' differences along x and along y, in one pass forward and one backward (a CPU
// backend and a CUDA kernel by device, one autograd node) instead of the hundred-odd LibTorch operations of their
// composition (pixel_loss_reference), which they are tested against. docs/performance.md.
#include <ATen/core/Tensor.h>

namespace sfgs::pixel_loss {

// prediction and target (H, W, 3) of one floating dtype and device, H and W >= 2 -> (4): the mean L1, the mean
// CIELAB L1, the mean x-gradient L1 and the mean y-gradient L1. Differentiable in the prediction only (the target is
// data: one that requires a gradient is refused).
at::Tensor pixel_losses(const at::Tensor& prediction, const at::Tensor& target);

// CIELAB (D65) of sRGB values in [0, 1] along the last axis, with L, a, b scaled by 1/100, 1/110, 1/110 so every
// channel spans about [-1, 1] like the RGB losses it is weighed against. Differentiable.
at::Tensor rgb_to_lab(const at::Tensor& rgb);

// The same four means as LibTorch operations (differentiable in both).
at::Tensor pixel_losses_reference(const at::Tensor& prediction, const at::Tensor& target);

}  // namespace sfgs::pixel_loss
