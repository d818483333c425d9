#pragma once
// The raw arrays of the gathered MLP (gathered_mlp.h) as its CUDA kernel takes them: torch-free, so nvcc compiles
// the kernel without a CUDA LibTorch. Half-precision values travel as their 16-bit patterns.
#include <cstdint>

namespace sfgs::gathered_mlp {

// The kernel's shape: hidden width (the avatar's default hidden_width) and the most outputs one row may have.
constexpr int kFusedWidth = 128;
constexpr int kFusedMaxOutputs = 8;

struct GatheredMlpArrays {
  const uint16_t* row_inputs;  // (rows, kFusedWidth) half: each row's share of the first layer, bias included
  const float* group_inputs;   // (groups, kFusedWidth): each group's share of the first layer
  const int32_t* groups;       // (rows); a row whose group is outside [0, group_count) gets NaN outputs
  int32_t group_count;
  const uint16_t* hidden_weight;  // (kFusedWidth, kFusedWidth) half, row-major (out, in)
  const float* hidden_bias;       // (kFusedWidth)
  const float* output_weight;     // (outputs, kFusedWidth)
  const float* output_bias;       // (outputs)
  int64_t rows;
  int outputs;  // 1 .. kFusedMaxOutputs
  float* out;   // (rows, outputs)
};

}  // namespace sfgs::gathered_mlp
