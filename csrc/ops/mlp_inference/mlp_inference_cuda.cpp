// CUDA backend of the MLP inference: the torch side of mlp_inference_kernels.h, queued on the device's current
// stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/mlp_inference/mlp_inference_kernels.h"
#include "ops/mlp_inference/backend.h"

namespace sfgs::mlp_inference::cuda {

bool fits(int hidden_layers, int input_width, at::Device device) {
  return cuda_kernels::fits(hidden_layers, input_width, device.index());
}

void forward(const MlpInferenceArrays& arrays, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::forward(arrays, at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::mlp_inference::cuda
