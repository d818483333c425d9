#pragma once
// The gathered MLP: a two-layer perceptron whose first layer is the sum of a per-row share and a per-group share
// gathered by each row's group,
//   out_i = W_out relu(W_hidden relu(row_inputs_i + group_inputs[groups_i]) + b_hidden) + b_out,
// the shape of the structure-aware offset (model/structure_offset.h): a point's fused feature projected once, and
// its dominant joint's pose projected per frame. For inference on CUDA it is one fused kernel (hidden width
// kFusedWidth, at most kFusedMaxOutputs outputs): the rows' share is read once, in half precision, the hidden layer
// runs on tensor cores with float accumulation, and nothing of the (N, hidden) activations reaches memory. The
// LibTorch composition is its reference (and the path for every other device, dtype or width). For training, the
// first layer alone is an op of its own (gathered_first_layer), and the layers after it are the network's.
#include <ATen/core/Tensor.h>

#include "ops/gathered_mlp/gathered_mlp_arrays.h"

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

// Inference (no gradient: refuses inputs or weights that require one, and grad mode), the dispatcher op
// sfgs::gathered_mlp. The same function as the reference; fused on CUDA (fuses()), where row_inputs should already be
// half (anything else is converted first, one extra pass) and groups int32 (converted likewise); the reference
// elsewhere. On the CPU a group outside [0, G) is an error; on CUDA (fused or not) it gives that row NaN outputs
// rather than a device read of every index. -> (N, O) in the weights' dtype (float32 where fused).
at::Tensor gathered_mlp(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups,
                        const GatheredMlpWeights& weights);

// The first layer for training: relu(row_inputs + group_inputs[groups]) -> (N, H), the structure offset's first
// activation. LibTorch composes it of a gather (embedding), an add and a ReLU forward, and embedding's sort-based
// backward and ReLU's threshold backward: about 0.45 ms of a 16 ms training step at 216k points on an H200. Here it is
// one kernel forward and one backward (a CPU backend and CUDA kernels of gathered_first_layer_math.h, one autograd
// node). The backward sums the groups' gradient per block of rows in shared memory and over the blocks in a fixed
// order (linear::column_sum): no global atomic adds piling N rows onto G. Within a block the CUDA table takes its
// warps' adds in the order they come, so the groups' gradient may differ in its last bits between runs (the CPU's does
// not). row_inputs (N, H) float or double; group_inputs (G, H), G >= 1, and groups (N) int64, on row_inputs' device
// (and group_inputs of its dtype). Differentiable in row_inputs and group_inputs (once). A group outside [0, G) is an
// error on the CPU; on CUDA, where checking would read the indices on the host (and break CUDA graph capture), its
// row gets NaN outputs and passes no gradient on, as gathered_mlp does.
at::Tensor gathered_first_layer(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups);
// The LibTorch composition it is tested against: at::relu(row_inputs + at::embedding(group_inputs, groups)).
at::Tensor gathered_first_layer_reference(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                          const at::Tensor& groups);

}  // namespace sfgs::gathered_mlp
