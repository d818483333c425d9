#pragma once
// CUDA kernels of the skinning op (csrc/ops/skin/skin.h), free of torch so that nvcc compiles them without a CUDA
// LibTorch: one thread per Gaussian takes skin_math.h's step. The glue (skin_cuda.cpp) passes raw pointers.
#include <cuda_runtime_api.h>

#include "ops/skin/skin_math.h"

namespace sfgs::skin::cuda_kernels {

template <typename T> void skin_forward(const SkinArrays<T>& arrays, cudaStream_t stream);
template <typename T> void skin_backward(const SkinGradientArrays<T>& arrays, cudaStream_t stream);

}  // namespace sfgs::skin::cuda_kernels
