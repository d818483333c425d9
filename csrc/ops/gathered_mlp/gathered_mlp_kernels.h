#pragma once
// CUDA kernel of the gathered MLP (csrc/ops/gathered_mlp/gathered_mlp.h), free of torch: one warp runs 16 rows through
// both layers, the hidden layer on tensor cores (half inputs, float accumulation), with the hidden weights in
// shared memory for every row the block takes. The glue (gathered_mlp_cuda.cpp) passes raw pointers.
#include <cuda_runtime_api.h>

#include "ops/gathered_mlp/gathered_mlp_arrays.h"

namespace sfgs::gathered_mlp::cuda_kernels {

void gathered_mlp_forward(const GatheredMlpArrays& arrays, cudaStream_t stream);

}  // namespace sfgs::gathered_mlp::cuda_kernels
