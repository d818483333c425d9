#pragma once
// CUDA kernels of the gathered first layer (csrc/ops/gathered_mlp/gathered_mlp.h: gathered_first_layer), free of torch
// so that nvcc compiles them without a CUDA LibTorch: a warp per row, its lanes over the row's columns, forward and
// backward; the backward's groups' gradient as one partial table per block. The glue
// (gathered_first_layer_cuda.cpp) allocates the partial tables and passes raw pointers.
#include <cstdint>

#include <cuda_runtime_api.h>

#include "ops/gathered_mlp/gathered_first_layer_math.h"

namespace sfgs::gathered_mlp::cuda_kernels {

// Blocks of the backward on `device` for `rows` rows: the partial tables it writes, one a block.
int64_t first_layer_backward_blocks(int64_t rows, int device);

template <typename T> void first_layer_forward(const FirstLayerArrays<T>& arrays, int device, cudaStream_t stream);
// arrays.partial_rows must be first_layer_backward_blocks(arrays.rows, device).
template <typename T>
void first_layer_backward(const FirstLayerGradientArrays<T>& arrays, int device, cudaStream_t stream);

}  // namespace sfgs::gathered_mlp::cuda_kernels
