#pragma once
// The contract between the fixed-point plane sampling (csrc/ops/plane_sampling/plane_sampling.cpp: the reads, the
// autograd node) and the backends of its backward (csrc/ops/plane_sampling/plane_sampling_cpu.cpp,
// csrc/ops/plane_sampling/plane_sampling_cuda.cpp): arrays of validated, contiguous tensors of one dtype on one device;
// grad_planes zeroed by the op.
#include <ATen/core/Tensor.h>

#include "ops/plane_sampling/plane_sampling_math.h"

namespace sfgs::plane_sampling {

namespace cpu {
void gradient(const PlaneGradientArrays<float>& arrays);
void gradient(const PlaneGradientArrays<double>& arrays);
}  // namespace cpu

// On `device`'s current stream.
namespace cuda {
void gradient(const PlaneGradientArrays<float>& arrays, at::Device device);
void gradient(const PlaneGradientArrays<double>& arrays, at::Device device);
}  // namespace cuda

}  // namespace sfgs::plane_sampling
