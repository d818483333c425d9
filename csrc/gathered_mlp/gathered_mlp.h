#pragma once
// The gathered MLP: a two-layer perceptron whose first layer is the sum of a per-row share and a per-group share
// gathered by each row's group,
//   out_i = W_out relu(W_hidden relu(row_inputs_i + group_inputs[groups_i]) + b_hidden) + b_out,
// the shape of the structure-aware offset (model/structure_offset.h): a point's fused feature projected once, and
// its dominant joint's pose projected per frame. For inference on CUDA it is one fused kernel (hidden width
// kFusedWidth, at most kFusedMaxOutputs outputs): the rows' share is read once, in half precision, the hidden layer
// runs on tensor cores with float accumulation, and nothing of the (N, hidden) activations reaches memory. The
// LibTorch composition is its reference (and the path for every other device, dtype or width).
#include <ATen/core/Tensor.h>

#include "gathered_mlp/gathered_mlp_arrays.h"

namespace sfgs::gathered_mlp {

struct GatheredMlpWeights {
  at::Tensor hidden_weight;  // (H, H), row-major (out, in)
  at::Tensor hidden_bias;    // (H)
  at::Tensor output_weight;  // (O, H)
  at::Tensor output_bias;    // (O)
};

// The LibTorch composition (differentiable): row_inputs (N, H), group_inputs (G, H), groups (N) integer in
// [0, G), all of one floating dtype (row_inputs may be half; it is converted) and device. -> (N, O).
at::Tensor gathered_mlp_reference(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                  const at::Tensor& groups, const GatheredMlpWeights& weights);

// Whether gathered_mlp runs the fused kernel for inputs like these: CUDA tensors of a build with the CUDA backend,
// H == kFusedWidth, O <= kFusedMaxOutputs, float32 weights.
bool fuses(const at::Tensor& row_inputs, const GatheredMlpWeights& weights);

// Inference (no gradient: refuses inputs or weights that require one, and grad mode). The same function as the
// reference; fused on CUDA (fuses()), where row_inputs should already be half (anything else is converted first,
// one extra pass), groups int32 (converted likewise), and a group outside [0, G) gives that row NaN outputs rather
// than a device read of every index; elsewhere the reference, which checks the groups. -> (N, O) float32 on CUDA,
// the weights' dtype elsewhere.
at::Tensor gathered_mlp(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups,
                        const GatheredMlpWeights& weights);

}  // namespace sfgs::gathered_mlp
