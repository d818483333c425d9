// CUDA backend of the skinning op: the torch side of skin_kernels.h, queued on the device's current stream.
#include <ATen/ATen.h>
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/skin/skin_kernels.h"
#include "ops/skin/backend.h"

namespace sfgs::skin::cuda {
namespace {

template <typename T> void backward_of(const SkinGradientArrays<T>& a, at::Device device, at::ScalarType dtype) {
  const c10::cuda::CUDAGuard guard(device);
  const int64_t values = cuda_kernels::backward_scratch_values(a);
  const at::Tensor scratch = at::empty({values}, at::TensorOptions().dtype(dtype).device(device));
  cuda_kernels::skin_backward(a, values > 0 ? scratch.data_ptr<T>() : nullptr, at::cuda::getCurrentCUDAStream());
}

}  // namespace

void forward(const SkinArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::skin_forward(a, at::cuda::getCurrentCUDAStream());
}

void forward(const SkinArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::skin_forward(a, at::cuda::getCurrentCUDAStream());
}

void backward(const SkinGradientArrays<float>& a, at::Device device) { backward_of(a, device, at::kFloat); }
void backward(const SkinGradientArrays<double>& a, at::Device device) { backward_of(a, device, at::kDouble); }

}  // namespace sfgs::skin::cuda
