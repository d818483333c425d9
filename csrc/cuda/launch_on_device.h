#pragma once
// The glue of the torch-free kernels (csrc/cuda/*_cuda.cpp): a launch function of (arrays, device index, stream),
// queued on `device`'s current stream with that device current.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

namespace sfgs::cuda_glue {

template <typename Arrays, typename Launch>
void launch_on_device(const Arrays& arrays, at::Device device, Launch launch) {
  const c10::cuda::CUDAGuard guard(device);
  launch(arrays, device.index(), at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::cuda_glue
