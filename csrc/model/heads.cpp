#include "model/heads.h"

#include <ATen/Functions.h>

namespace sfgs::model {

MlpShape CanonicalHeadsImpl::geometry_shape(int64_t feature_width, int64_t hidden_width) {
  return MlpShape{{feature_width},
                  {hidden_width, hidden_width, hidden_width},
                  3 + 1,
                  /*group_norm=*/true,
                  /*zero_output=*/true};
}

MlpShape CanonicalHeadsImpl::colour_shape(int64_t feature_width, int64_t hidden_width) {
  return MlpShape{{feature_width},
                  {hidden_width, hidden_width, hidden_width},
                  3,
                  /*group_norm=*/true,
                  /*zero_output=*/true};
}

CanonicalHeadsImpl::CanonicalHeadsImpl(int64_t feature_width, int64_t hidden_width) {
  geometry_ = register_module("geometry", Mlp(geometry_shape(feature_width, hidden_width)));
  colour_ = register_module("colour", Mlp(colour_shape(feature_width, hidden_width)));
}

CanonicalHeadOutput CanonicalHeadsImpl::forward(const at::Tensor& features) const {
  const at::Tensor geometry = geometry_->forward({features});
  CanonicalHeadOutput out;
  out.mean_offset = geometry.narrow(1, 0, 3);
  out.log_scale_offset = geometry.select(1, 3);
  out.colour_logits = colour_->forward({features});
  return out;
}

}  // namespace sfgs::model
