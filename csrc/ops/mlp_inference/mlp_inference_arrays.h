#pragma once
// The raw arrays of the fused MLP inference (mlp_inference.h) as its CUDA kernel takes them: torch-free, so nvcc
// compiles the kernel without a CUDA LibTorch. Every array is float32; row strides are in elements.
#include <cstdint>

namespace sfgs::mlp_inference {

// The kernel's shape: the avatar's hidden width and GroupNorm groups (common/constants.h), at most
// kFusedMaxInputWidth input columns over at most kFusedMaxInputs blocks, kFusedMaxHiddenLayers hidden layers and
// kFusedMaxOutputs outputs.
constexpr int kFusedWidth = 128;
constexpr int kFusedGroups = 4;
constexpr int kFusedMaxInputWidth = 128;
constexpr int kFusedMaxInputs = 3;
constexpr int kFusedMaxHiddenLayers = 3;
constexpr int kFusedMaxOutputs = 8;

// A block of the first layer's input columns and its share of the first layer's weight.
struct InputBlock {
  const float* values = nullptr;  // (rows, width), rows `values_stride` apart
  int64_t values_stride = 0;
  const float* weight = nullptr;  // (kFusedWidth, width), rows `weight_stride` apart
  int64_t weight_stride = 0;
  int width = 0;
};

struct MlpInferenceArrays {
  InputBlock inputs[kFusedMaxInputs];
  int input_count = 0;
  // Every block's width and row stride even and its values 8-byte aligned: the kernel reads column pairs at once.
  bool paired_inputs = false;
  const float* base = nullptr;        // (rows, kFusedWidth) added to the first layer's product, or null
  const float* first_bias = nullptr;  // (kFusedWidth)
  // Hidden layer k >= 1: (kFusedWidth, kFusedWidth) row-major (out, in) and (kFusedWidth).
  const float* hidden_weights[kFusedMaxHiddenLayers - 1] = {};
  const float* hidden_biases[kFusedMaxHiddenLayers - 1] = {};
  const float* norm_weights[kFusedMaxHiddenLayers] = {};  // GroupNorm's gamma and beta per hidden layer (kFusedWidth)
  const float* norm_biases[kFusedMaxHiddenLayers] = {};
  int hidden_layers = 0;                 // 1 .. kFusedMaxHiddenLayers
  const float* output_weight = nullptr;  // (outputs, kFusedWidth)
  const float* output_bias = nullptr;    // (outputs)
  int outputs = 0;                       // 1 .. kFusedMaxOutputs
  float epsilon = 0.f;
  int64_t rows = 0;
  float* out = nullptr;  // (rows, outputs)
};

}  // namespace sfgs::mlp_inference
