#pragma once
// CUDA kernels of the skinning op (csrc/ops/skin/skin.h), free of torch so that nvcc compiles them without a CUDA
// LibTorch: one thread per Gaussian takes skin_math.h's step. The glue (skin_cuda.cpp) passes raw pointers.
#include <cstdint>

#include <cuda_runtime_api.h>

#include "ops/skin/skin_math.h"

namespace sfgs::skin::cuda_kernels {

// Values of scratch memory skin_backward needs (the per-block sums of the transforms' gradient); 0 when it is not
// wanted.
template <typename T> int64_t backward_scratch_values(const SkinGradientArrays<T>& arrays);

template <typename T> void skin_forward(const SkinArrays<T>& arrays, cudaStream_t stream);
// `scratch`: backward_scratch_values(arrays) values of device memory (may be null when that is 0).
template <typename T> void skin_backward(const SkinGradientArrays<T>& arrays, T* scratch, cudaStream_t stream);

}  // namespace sfgs::skin::cuda_kernels
