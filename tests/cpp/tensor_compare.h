#pragma once
// What every kernel suite compares with: float64 options and the largest absolute difference of two tensors.
#include <ATen/ATen.h>

namespace sfgs::testing {

inline const at::TensorOptions kF64 = at::TensorOptions().dtype(at::kDouble);

// The largest |a - b|, computed in float64 on the CPU whatever the tensors' device and dtype; 0 for empty tensors.
inline double max_difference(const at::Tensor& a, const at::Tensor& b) {
  if (a.numel() == 0) return 0.0;
  return (a.to(at::kCPU, at::kDouble) - b.to(at::kCPU, at::kDouble)).abs().max().item<double>();
}

}  // namespace sfgs::testing
