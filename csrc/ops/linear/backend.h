#pragma once
// The contract between the linear layer (csrc/ops/linear/linear.cpp) and its CUDA column sum
// (csrc/ops/linear/linear_cuda.cpp); the CPU sums with at::sum.
#include <ATen/core/Tensor.h>

namespace sfgs::linear::cuda {

// rows (R, C) contiguous float or double on a CUDA device -> (C) on its current stream.
at::Tensor column_sum(const at::Tensor& rows);

}  // namespace sfgs::linear::cuda
