#pragma once
// The contract between the gathered MLP (gathered_mlp.cpp: validation, conversions) and its CUDA kernel's glue
// (csrc/cuda/gathered_mlp_cuda.cpp; csrc/cuda/cuda_unavailable.cpp in builds without CUDA).
#include <c10/core/Device.h>

#include "gathered_mlp/gathered_mlp_arrays.h"

namespace sfgs::gathered_mlp::cuda {

bool available();
// Queues the kernel on the device's current stream; the arrays are validated and contiguous.
void forward(const GatheredMlpArrays& arrays, at::Device device);

}  // namespace sfgs::gathered_mlp::cuda
