#pragma once
// CUDA kernels of the feature-fusion ops (csrc/ops/feature_fusion/feature_fusion.h), free of torch so that nvcc
// compiles them without a CUDA LibTorch: element-wise and row-gather grid-stride loops, in float4 where the float
// arrays allow. The glue (feature_fusion_cuda.cpp) passes raw pointers.
#include <cuda_runtime_api.h>

#include "ops/feature_fusion/feature_fusion_math.h"

namespace sfgs::feature_fusion::cuda_kernels {

template <typename T> void gated_mix(const GatedMixArrays<T>& arrays, int device, cudaStream_t stream);
template <typename T> void gated_mix_backward(const GatedMixGradientArrays<T>& arrays, int device, cudaStream_t stream);
template <typename T> void gather_rows(const RowGatherArrays<T>& arrays, int device, cudaStream_t stream);

}  // namespace sfgs::feature_fusion::cuda_kernels
