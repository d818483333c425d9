// CUDA backend of the skinning op: the torch side of skin_kernels.h, queued on the device's current stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/skin/skin_kernels.h"
#include "ops/skin/backend.h"

namespace sfgs::skin::cuda {

void forward(const SkinArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::skin_forward(a, at::cuda::getCurrentCUDAStream());
}

void forward(const SkinArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::skin_forward(a, at::cuda::getCurrentCUDAStream());
}

void backward(const SkinGradientArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::skin_backward(a, at::cuda::getCurrentCUDAStream());
}

void backward(const SkinGradientArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::skin_backward(a, at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::skin::cuda
