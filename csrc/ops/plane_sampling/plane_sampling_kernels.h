#pragma once
// CUDA kernel of the planes' backward (csrc/ops/plane_sampling/plane_sampling.h), free of torch so that nvcc compiles
// it without a CUDA LibTorch: a warp per chunk of reads, a lane per channel. The glue (plane_sampling_cuda.cpp) passes
// raw pointers.
#include <cuda_runtime_api.h>

#include "ops/plane_sampling/plane_sampling_math.h"

namespace sfgs::plane_sampling::cuda_kernels {

template <typename T> void gradient(const PlaneGradientArrays<T>& arrays, cudaStream_t stream);

}  // namespace sfgs::plane_sampling::cuda_kernels
