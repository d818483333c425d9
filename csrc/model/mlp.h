#pragma once
// The multilayer perceptron every avatar module is built from. Its input may come in groups: the first layer is
// then a sum of one linear map per group, which is the same function as one linear layer on the concatenated
// groups, but lets a group that changes rarely (a point's fused feature) be projected once and reused while
// another group (a pose) changes every frame.
#include <cstdint>
#include <vector>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "ops/gathered_mlp/gathered_mlp.h"
#include "ops/mlp_inference/mlp_inference.h"
#include "model/constants.h"

namespace sfgs::model {

struct MlpShape {
  std::vector<int64_t> input_widths;   // one per input group, in the order of the concatenation
  std::vector<int64_t> hidden_widths;  // each hidden layer: linear, GroupNorm when group_norm, ReLU
  int64_t output_width = 0;            // no hidden layers: the first layer is the (linear) output
  bool group_norm = false;             // GroupNorm(kMlpGroupNormGroups) before every ReLU, as the authors' heads
                                       // (fused with its affine map, the ReLU and the layer's bias:
                                       // ops/group_norm/group_norm.h)
  bool zero_output = false;            // the output layer starts at zero, so the network starts as the constant 0
};

// Parameters are initialised as torch.nn.Linear's (uniform in +-1/sqrt(fan in)); GroupNorm as identity.
class MlpImpl : public torch::nn::Module {
 public:
  explicit MlpImpl(MlpShape shape);

  // (N, input_widths[group]) -> (N, first layer width): group 0 carries the first layer's bias, except where
  // bias_in_activation().
  at::Tensor project(size_t group, const at::Tensor& input) const;
  // A GroupNorm network adds its first layer's bias in the first activation (the fused GroupNorm op), not in
  // project(0): the op sums the bias's gradient in its own backward pass, where a linear layer's bias costs one more
  // column sum over the N rows (about 0.2 ms at 216k rows on an H200). finish() takes the projections' sum either way.
  bool bias_in_activation() const;
  // base + project(group, input) with the sum in the matrix product (one pass fewer over the (N, width) rows).
  at::Tensor project_add(size_t group, const at::Tensor& input, const at::Tensor& base) const;
  // The sum of the projections of every group -> (N, output_width).
  at::Tensor finish(const at::Tensor& first_layer) const;
  // The layers after the first hidden layer's activation (N, hidden_widths[0]) -> (N, output_width), for a caller
  // that computes that activation itself (the structure offset's fused first layer, gathered_mlp.h); finish(x) is
  // finish_activated of x's first activation. Networks without hidden layers have no such activation: an error.
  at::Tensor finish_activated(const at::Tensor& first_activation) const;
  // finish(project_add(group, cat(parts, 1), base)): the group's input given as column blocks, so that inference
  // on CUDA runs the whole network as one kernel (mlp_inference.h) without concatenating them.
  at::Tensor finish_from(const at::Tensor& base, size_t group, const std::vector<at::Tensor>& parts) const;
  // All groups at once; at inference on CUDA one kernel (mlp_inference.h) where the shape allows.
  at::Tensor forward(const std::vector<at::Tensor>& inputs) const;

  const MlpShape& shape() const { return shape_; }
  // The layers after the first as the gathered MLP takes them (gathered_mlp.h): for a network of two hidden layers
  // without GroupNorm, whose first layer is the gathered sum.
  gathered_mlp::GatheredMlpWeights gathered_weights() const;
  // The network as the fused inference takes it, its first layer's input as `widths`' column blocks of group
  // `group` (all groups in order when `widths` is empty): for a GroupNorm network with hidden layers.
  mlp_inference::Network inference_network(size_t group, const std::vector<int64_t>& widths) const;
  // Parameters of a network of this shape (the formula docs/avatar.md gives).
  static int64_t parameter_count(const MlpShape& shape);

 private:
  // Whether this call may take the fused inference: no gradient, a GroupNorm network with hidden layers.
  bool infers() const;
  // Hidden layer `layer`'s activation of its linear part `pre` (bias included, but for the first layer where
  // bias_in_activation(): then it is added here).
  at::Tensor activate(size_t layer, const at::Tensor& pre) const;

  MlpShape shape_;
  std::vector<at::Tensor> input_weights_;  // per group (first width, input width)
  at::Tensor input_bias_;
  std::vector<at::Tensor> hidden_weights_, hidden_biases_;  // layers after the first hidden one
  std::vector<at::Tensor> norm_weights_, norm_biases_;      // per hidden layer, when group_norm
  at::Tensor output_weight_, output_bias_;                  // undefined without hidden layers
};
TORCH_MODULE(Mlp);

}  // namespace sfgs::model
