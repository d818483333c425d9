#pragma once
// CUDA kernels of the fused pixel-loss op (csrc/ops/pixel_loss/pixel_loss.h), free of torch so that nvcc compiles them
// without a CUDA LibTorch: one thread per pixel, the forward's sums reduced per block. The glue
// (pixel_loss_cuda.cpp) passes raw pointers.
#include <cstdint>

#include <cuda_runtime_api.h>

#include "ops/pixel_loss/pixel_loss_math.h"

namespace sfgs::pixel_loss::cuda_kernels {

// Partial-sum rows the forward writes for an image of this size (one per block).
int64_t partials(int height, int width);
template <typename T> void forward(const PixelLossArrays<T>& arrays, cudaStream_t stream);
template <typename T> void backward(const PixelLossGradientArrays<T>& arrays, cudaStream_t stream);

}  // namespace sfgs::pixel_loss::cuda_kernels
