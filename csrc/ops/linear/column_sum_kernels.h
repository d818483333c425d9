#pragma once
// The CUDA column sum of the linear layer (csrc/ops/linear/linear.h), free of torch so that nvcc compiles it without a
// CUDA LibTorch. The glue (linear_cuda.cpp) allocates the partial rows and passes raw pointers.
#include <cstdint>

#include <cuda_runtime_api.h>

namespace sfgs::linear::cuda_kernels {

// Chunks of rows the first pass cuts (R, C) into on `device` (1: the sum needs one pass, straight into the result).
int64_t chunks(int64_t rows, int64_t columns, int device);

// out (C) = column sums of rows (R, C); `partials` (chunks, C) holds the first pass's sums when chunks > 1.
template <typename T>
void column_sum(const T* rows, int64_t row_count, int64_t columns, T* partials, int64_t chunk_count, T* out,
                cudaStream_t stream);

}  // namespace sfgs::linear::cuda_kernels
