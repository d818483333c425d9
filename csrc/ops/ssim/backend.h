#pragma once
// The contract between the fused SSIM (csrc/ops/ssim/ssim.cpp: validation, autograd) and its two backends
// (csrc/ops/ssim/ssim_cpu.cpp, csrc/ops/ssim/ssim_cuda.cpp): arrays of validated, contiguous tensors of one dtype on
// one device, outputs allocated by the op. Each backend says how many partial sums of the SSIM map its forward writes,
// so the op can allocate them and add them up on the device.
#include <ATen/core/Tensor.h>

#include "ops/ssim/ssim_math.h"

namespace sfgs::ssim {

namespace cpu {
int64_t partial_sums(int64_t height, int64_t width, int64_t channels);
void forward(const SsimArrays<float>& arrays);
void forward(const SsimArrays<double>& arrays);
void backward(const SsimGradientArrays<float>& arrays);
void backward(const SsimGradientArrays<double>& arrays);
}  // namespace cpu

// On `device`'s current stream.
namespace cuda {
// One partial sum per tile of the kernels, whose size depends on the dtype.
int64_t partial_sums(int64_t height, int64_t width, int64_t channels, at::ScalarType dtype);
void forward(const SsimArrays<float>& arrays, at::Device device);
void forward(const SsimArrays<double>& arrays, at::Device device);
void backward(const SsimGradientArrays<float>& arrays, at::Device device);
void backward(const SsimGradientArrays<double>& arrays, at::Device device);
}  // namespace cuda

}  // namespace sfgs::ssim
