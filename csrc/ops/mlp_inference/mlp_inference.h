#pragma once
// Inference of the avatar's GroupNorm MLPs (model/mlp.h) as one kernel: every hidden layer is linear, GroupNorm,
// affine and ReLU,
//   h_1 = relu(gamma_1 * GroupNorm(sum_b inputs_b W_b^T + base + bias_1) + beta_1),
//   h_k = relu(gamma_k * GroupNorm(h_{k-1} W_k^T + b_k) + beta_k),   out = h_L W_out^T + b_out,
// the canonical heads' and the colour offset's shape. LibTorch runs such a network as a matrix product and a
// GroupNorm pass per layer, each an (N, H) round trip through memory: at 216k points about 0.5 ms a network on an
// H200, most of a replayed frame's time path. On CUDA (fuses()) one kernel reads each row's inputs once, keeps its
// activations in registers through every layer (tensor cores, half operands with 11 significant bits as TF32's,
// float accumulation and float GroupNorm) and writes its few outputs: 0.19 ms a network there. Inputs beyond half's
// range saturate to +-65504; a NaN stays NaN. The LibTorch composition is its reference
// and the path for every other device, dtype or shape.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

#include "ops/mlp_inference/mlp_inference_arrays.h"

namespace sfgs::mlp_inference {

struct Network {
  std::vector<at::Tensor> input_weights;   // per input block (H, I_b): the first layer's columns for that block
  at::Tensor first_bias;                   // (H), added before the first GroupNorm
  std::vector<at::Tensor> hidden_weights;  // per hidden layer after the first (H, H), row-major (out, in)
  std::vector<at::Tensor> hidden_biases;   // (H) each
  std::vector<at::Tensor> norm_weights;    // GroupNorm's gamma per hidden layer (H)
  std::vector<at::Tensor> norm_biases;     // and its beta
  at::Tensor output_weight;                // (O, H)
  at::Tensor output_bias;                  // (O)
  int64_t groups = 0;
  double epsilon = 0.0;
};

// The LibTorch composition (differentiable): inputs per block (N, I_b), base (N, H) or undefined, all of the
// network's dtype and device. -> (N, O).
at::Tensor reference(const std::vector<at::Tensor>& inputs, const at::Tensor& base, const Network& network);

// Whether run() takes the fused kernel for these: CUDA tensors of a build with the CUDA backend, float32, H ==
// kFusedWidth with kFusedGroups groups, at most kFusedMaxInputWidth input columns in at most kFusedMaxInputs
// blocks, kFusedMaxHiddenLayers hidden layers and kFusedMaxOutputs outputs, on a device that gives a block the
// kernel's shared memory (three hidden layers: 98.5 KiB for the heads' 96 inputs, at most 106.5 KiB; an RTX 4090
// gives 99 KiB, an H100 or H200 227 KiB).
bool fuses(const std::vector<at::Tensor>& inputs, const Network& network);

// Inference (no gradient: refuses inputs or weights that require one in grad mode), the dispatcher op
// sfgs::mlp_inference: the reference's function, fused where fuses(), the reference elsewhere. Input blocks and
// weights may be column slices (row strides are kept).
at::Tensor run(const std::vector<at::Tensor>& inputs, const at::Tensor& base, const Network& network);

}  // namespace sfgs::mlp_inference
