#pragma once
// CUDA kernel of the fused MLP inference (csrc/ops/mlp_inference/mlp_inference.h), free of torch: one warp runs 16 rows
// through every layer on tensor cores (half operands, float accumulation), the activations in registers, the weights
// in shared memory. The glue (mlp_inference_cuda.cpp) passes raw pointers.
#include <cuda_runtime_api.h>

#include "ops/mlp_inference/mlp_inference_arrays.h"

namespace sfgs::mlp_inference::cuda_kernels {

// Shared memory a block of the kernel needs for a network of `hidden_layers` hidden layers and `input_width` input
// columns, in bytes.
int shared_bytes(int hidden_layers, int input_width);
// Whether `device` gives a block that much shared memory.
bool fits(int hidden_layers, int input_width, int device);
// Queues the kernel on `stream`; the arrays are validated.
void forward(const MlpInferenceArrays& arrays, cudaStream_t stream);

}  // namespace sfgs::mlp_inference::cuda_kernels
