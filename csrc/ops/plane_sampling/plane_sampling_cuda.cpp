// CUDA backend of the planes' backward: the torch side of plane_sampling_kernels.h, queued on the device's current
// stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/plane_sampling/plane_sampling_kernels.h"
#include "ops/plane_sampling/backend.h"

namespace sfgs::plane_sampling::cuda {

void gradient(const PlaneGradientArrays<float>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::gradient(a, at::cuda::getCurrentCUDAStream());
}

void gradient(const PlaneGradientArrays<double>& a, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::gradient(a, at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::plane_sampling::cuda
