#pragma once
// The contract between the gathered-MLP ops (gathered_mlp.cpp: the inference MLP; gathered_first_layer.cpp: the
// first layer as a training op; validation, conversions, autograd) and their backends: the CPU backend of the first
// layer (csrc/ops/gathered_mlp/gathered_first_layer_cpu.cpp; the inference MLP's CPU path is its LibTorch reference)
// and the CUDA kernels' glue (csrc/ops/gathered_mlp/gathered_mlp_cuda.cpp,
// csrc/ops/gathered_mlp/gathered_first_layer_cuda.cpp; only in builds with CUDA). Arrays
// of validated, contiguous tensors of one dtype on one device, outputs allocated by the ops; each first-layer backend
// says how many partial tables of the groups' gradient its backward writes, so the op can allocate them.
#include <cstdint>

#include <c10/core/Device.h>

#include "ops/gathered_mlp/gathered_first_layer_math.h"
#include "ops/gathered_mlp/gathered_mlp_arrays.h"

namespace sfgs::gathered_mlp {

namespace cpu {
int64_t first_layer_partial_rows(int64_t rows);
void first_layer_forward(const FirstLayerArrays<float>& arrays);
void first_layer_forward(const FirstLayerArrays<double>& arrays);
void first_layer_backward(const FirstLayerGradientArrays<float>& arrays);
void first_layer_backward(const FirstLayerGradientArrays<double>& arrays);
}  // namespace cpu

// On `device`'s current stream.
namespace cuda {
// Queues the inference kernel; the arrays are validated and contiguous.
void forward(const GatheredMlpArrays& arrays, at::Device device);
int64_t first_layer_partial_rows(int64_t rows, at::Device device);
void first_layer_forward(const FirstLayerArrays<float>& arrays, at::Device device);
void first_layer_forward(const FirstLayerArrays<double>& arrays, at::Device device);
void first_layer_backward(const FirstLayerGradientArrays<float>& arrays, at::Device device);
void first_layer_backward(const FirstLayerGradientArrays<double>& arrays, at::Device device);
}  // namespace cuda

}  // namespace sfgs::gathered_mlp
