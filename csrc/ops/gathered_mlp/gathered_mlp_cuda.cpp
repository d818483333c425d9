// CUDA backend of the gathered MLP: the torch side of gathered_mlp_kernels.h, queued on the device's current stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/gathered_mlp/gathered_mlp_kernels.h"
#include "ops/gathered_mlp/backend.h"

namespace sfgs::gathered_mlp::cuda {

void forward(const GatheredMlpArrays& arrays, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::gathered_mlp_forward(arrays, at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::gathered_mlp::cuda
