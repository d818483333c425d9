#pragma once
// The canonical heads: MLPs from the fused feature to the position offset and log-scale offset (one geometry
// network with a 3 + 1 output) and to the colour logits. Their output layers start at zero, so a new avatar is
// the body-model mesh with the initial scales and grey colours.
#include <cstdint>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "model/mlp.h"

namespace sfgs::model {

struct CanonicalHeadOutput {
  at::Tensor mean_offset;       // (N, 3)
  at::Tensor log_scale_offset;  // (N): added to the initial log-scale
  at::Tensor colour_logits;     // (N, 3): the colour before the offset and the sigmoid
};

class CanonicalHeadsImpl : public torch::nn::Module {
 public:
  CanonicalHeadsImpl(int64_t feature_width, int64_t hidden_width);
  CanonicalHeadOutput forward(const at::Tensor& features) const;

  // The authors' geometry and colour networks: three hidden layers with GroupNorm.
  static MlpShape geometry_shape(int64_t feature_width, int64_t hidden_width);
  static MlpShape colour_shape(int64_t feature_width, int64_t hidden_width);

 private:
  Mlp geometry_{nullptr}, colour_{nullptr};
};
TORCH_MODULE(CanonicalHeads);

}  // namespace sfgs::model
