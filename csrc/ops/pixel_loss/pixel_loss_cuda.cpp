// CUDA backend of the fused pixel-loss op: the torch side of pixel_loss_kernels.h, queued on the device's current
// stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/pixel_loss/pixel_loss_kernels.h"
#include "ops/pixel_loss/backend.h"

namespace sfgs::pixel_loss::cuda {

int64_t partials(int height, int width) { return cuda_kernels::partials(height, width); }

void forward(const PixelLossArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::forward(a, at::cuda::getCurrentCUDAStream());
}

void forward(const PixelLossArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::forward(a, at::cuda::getCurrentCUDAStream());
}

void backward(const PixelLossGradientArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::backward(a, at::cuda::getCurrentCUDAStream());
}

void backward(const PixelLossGradientArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::backward(a, at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::pixel_loss::cuda
