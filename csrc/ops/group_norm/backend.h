#pragma once
// The contract between the fused GroupNorm op (csrc/ops/group_norm/group_norm.cpp: validation, autograd) and its two
// backends (csrc/ops/group_norm/group_norm_cpu.cpp, csrc/ops/group_norm/group_norm_cuda.cpp): arrays of validated,
// contiguous tensors of one dtype on one device, outputs allocated by the op. Each backend says how many partial rows
// of column sums its backward writes, so the op can allocate them.
#include <ATen/core/Tensor.h>

#include "ops/group_norm/group_norm_math.h"

namespace sfgs::group_norm {

namespace cpu {
int64_t partial_rows(int64_t rows);
void forward(const GroupNormArrays<float>& arrays);
void forward(const GroupNormArrays<double>& arrays);
void backward(const GroupNormGradientArrays<float>& arrays);
void backward(const GroupNormGradientArrays<double>& arrays);
}  // namespace cpu

// On `device`'s current stream.
namespace cuda {
// Whether the kernels take rows of `channels` in `groups`.
bool supports(int64_t channels, int64_t groups);
int64_t partial_rows(int64_t rows, at::Device device);
void forward(const GroupNormArrays<float>& arrays, at::Device device);
void forward(const GroupNormArrays<double>& arrays, at::Device device);
void backward(const GroupNormGradientArrays<float>& arrays, at::Device device);
void backward(const GroupNormGradientArrays<double>& arrays, at::Device device);
}  // namespace cuda

}  // namespace sfgs::group_norm
