#pragma once
// The contract between the feature-fusion ops (csrc/ops/feature_fusion/feature_fusion.cpp: validation, autograd) and
// their two backends (csrc/ops/feature_fusion/feature_fusion_cpu.cpp, csrc/ops/feature_fusion/feature_fusion_cuda.cpp):
// arrays of validated, contiguous tensors of one dtype on one device, outputs allocated by the ops.
#include <ATen/core/Tensor.h>

#include "ops/feature_fusion/feature_fusion_math.h"

namespace sfgs::feature_fusion {

namespace cpu {
void gated_mix(const GatedMixArrays<float>& arrays);
void gated_mix(const GatedMixArrays<double>& arrays);
void gated_mix_backward(const GatedMixGradientArrays<float>& arrays);
void gated_mix_backward(const GatedMixGradientArrays<double>& arrays);
void gather_rows(const RowGatherArrays<float>& arrays);
void gather_rows(const RowGatherArrays<double>& arrays);
}  // namespace cpu

// On `device`'s current stream.
namespace cuda {
void gated_mix(const GatedMixArrays<float>& arrays, at::Device device);
void gated_mix(const GatedMixArrays<double>& arrays, at::Device device);
void gated_mix_backward(const GatedMixGradientArrays<float>& arrays, at::Device device);
void gated_mix_backward(const GatedMixGradientArrays<double>& arrays, at::Device device);
void gather_rows(const RowGatherArrays<float>& arrays, at::Device device);
void gather_rows(const RowGatherArrays<double>& arrays, at::Device device);
}  // namespace cuda

}  // namespace sfgs::feature_fusion
