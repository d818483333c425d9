#pragma once
// CUDA kernels of the fused GroupNorm + ReLU op (csrc/ops/group_norm/group_norm.h), free of torch so that nvcc compiles
// them without a CUDA LibTorch: one warp per row, each lane holding every 32nd channel in registers. The glue
// (group_norm_cuda.cpp) passes raw pointers.
#include <cstdint>

#include <cuda_runtime_api.h>

#include "ops/group_norm/group_norm_math.h"
#include "ops/group_norm/constants.h"

namespace sfgs::group_norm::cuda_kernels {

// Rows of `channels` in `groups` the kernels take: group sizes a multiple of the warp, within
// kGroupNormMaxChannels.
bool supports(int64_t channels, int64_t groups);
// Blocks of the backward on `device` for `rows` rows, one partial row of column sums each.
int64_t backward_blocks(int64_t rows, int device);

template <typename T> void forward(const GroupNormArrays<T>& arrays, int device, cudaStream_t stream);
template <typename T> void backward(const GroupNormGradientArrays<T>& arrays, int device, cudaStream_t stream);

}  // namespace sfgs::group_norm::cuda_kernels
