#pragma once
// CUDA kernels of the fused SSIM (csrc/ops/ssim/ssim.h), free of torch so that nvcc compiles them without a CUDA
// LibTorch: a block per tile of 32 columns and kSsimTileRows rows of one channel, filtered separably in shared
// memory. The glue (ssim_cuda.cpp) passes raw pointers.
#include <cstdint>

#include <cuda_runtime_api.h>

#include "ops/ssim/ssim_math.h"
#include "ops/ssim/constants.h"

namespace sfgs::ssim::cuda_kernels {

// The forward's blocks for an image, each writing one partial sum of the SSIM map (the tile depends on the dtype).
template <typename T> int64_t tile_count(int64_t height, int64_t width, int64_t channels);

template <typename T> void forward(const SsimArrays<T>& arrays, cudaStream_t stream);
template <typename T> void backward(const SsimGradientArrays<T>& arrays, cudaStream_t stream);

}  // namespace sfgs::ssim::cuda_kernels
