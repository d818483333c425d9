// CUDA backend of the fused GroupNorm + ReLU op: the torch side of group_norm_kernels.h, queued on the device's
// current stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/group_norm/group_norm_kernels.h"
#include "ops/group_norm/backend.h"

namespace sfgs::group_norm::cuda {

bool supports(int64_t channels, int64_t groups) { return cuda_kernels::supports(channels, groups); }
int64_t partial_rows(int64_t rows, at::Device device) { return cuda_kernels::backward_blocks(rows, device.index()); }

void forward(const GroupNormArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::forward(a, device.index(), at::cuda::getCurrentCUDAStream());
}

void forward(const GroupNormArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::forward(a, device.index(), at::cuda::getCurrentCUDAStream());
}

void backward(const GroupNormGradientArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::backward(a, device.index(), at::cuda::getCurrentCUDAStream());
}

void backward(const GroupNormGradientArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::backward(a, device.index(), at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::group_norm::cuda
