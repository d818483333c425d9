// CUDA backend of the fused SSIM: the torch side of ssim_kernels.h, queued on the device's current stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/ssim/ssim_kernels.h"
#include "ops/ssim/backend.h"

namespace sfgs::ssim::cuda {

int64_t partial_sums(int64_t height, int64_t width, int64_t channels, at::ScalarType dtype) {
  return dtype == at::kDouble ? cuda_kernels::tile_count<double>(height, width, channels)
                              : cuda_kernels::tile_count<float>(height, width, channels);
}

void forward(const SsimArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::forward(a, at::cuda::getCurrentCUDAStream());
}

void forward(const SsimArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::forward(a, at::cuda::getCurrentCUDAStream());
}

void backward(const SsimGradientArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::backward(a, at::cuda::getCurrentCUDAStream());
}

void backward(const SsimGradientArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::backward(a, at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::ssim::cuda
