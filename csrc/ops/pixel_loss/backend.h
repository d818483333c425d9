#pragma once
// The contract between the fused pixel-loss op (csrc/ops/pixel_loss/pixel_loss.cpp: validation, autograd) and its two
// backends (csrc/ops/pixel_loss/pixel_loss_cpu.cpp, csrc/ops/pixel_loss/pixel_loss_cuda.cpp): arrays of validated,
// contiguous tensors of one dtype on one device; the forward writes partial sums (the op sums them), the backward the
// whole gradient.
#include <ATen/core/Tensor.h>

#include "ops/pixel_loss/pixel_loss_math.h"

namespace sfgs::pixel_loss {

namespace cpu {
int64_t partials(int height);
void forward(const PixelLossArrays<float>& arrays);
void forward(const PixelLossArrays<double>& arrays);
void backward(const PixelLossGradientArrays<float>& arrays);
void backward(const PixelLossGradientArrays<double>& arrays);
}  // namespace cpu

// On `device`'s current stream.
namespace cuda {
int64_t partials(int height, int width);
void forward(const PixelLossArrays<float>& arrays, at::Device device);
void forward(const PixelLossArrays<double>& arrays, at::Device device);
void backward(const PixelLossGradientArrays<float>& arrays, at::Device device);
void backward(const PixelLossGradientArrays<double>& arrays, at::Device device);
}  // namespace cuda

}  // namespace sfgs::pixel_loss
