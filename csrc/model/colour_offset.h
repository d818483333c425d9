#pragma once
// SFGS's structure-aware colour offset: a point's pose embedding p_i = sum_j w_ij r_j (the 6D local joint
// rotations weighted by its skinning weights) and its posed normal n_i, with its fused feature, go through an MLP
// to an offset of the colour logits. The fused feature's share of the first layer can be computed once.
#include <cstdint>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "model/mlp.h"

namespace sfgs::model {

class ColourOffsetImpl : public torch::nn::Module {
 public:
  ColourOffsetImpl(int64_t feature_width, int64_t hidden_width);

  // (N, feature_width) -> (N, hidden_width): the fused feature's share of the first layer.
  at::Tensor project_features(const at::Tensor& features) const;
  // pose_embedding (N, 6), normals (N, 3) -> colour-logit offsets (N, 3).
  at::Tensor forward(const at::Tensor& feature_projection, const at::Tensor& pose_embedding,
                     const at::Tensor& normals) const;

  // The authors' network: three hidden layers with GroupNorm.
  static MlpShape shape(int64_t feature_width, int64_t hidden_width);

 private:
  Mlp mlp_{nullptr};  // groups: fused feature, [pose embedding; normal]
};
TORCH_MODULE(ColourOffset);

}  // namespace sfgs::model
