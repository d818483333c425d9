#pragma once
// The contract between the MLP inference op (mlp_inference.cpp: validation, the reference, the choice of path) and
// its CUDA kernel's glue (csrc/ops/mlp_inference/mlp_inference_cuda.cpp, built only with CUDA). The CPU path is the
// LibTorch reference.
#include <c10/core/Device.h>

#include "ops/mlp_inference/mlp_inference_arrays.h"

namespace sfgs::mlp_inference::cuda {

// Whether `device` gives a block the kernel's shared memory for this many hidden layers and input columns.
bool fits(int hidden_layers, int input_width, at::Device device);
// Queues the kernel on the device's current stream; the arrays are validated.
void forward(const MlpInferenceArrays& arrays, at::Device device);

}  // namespace sfgs::mlp_inference::cuda
