#include "model/colour_offset.h"

#include <ATen/Functions.h>

namespace sfgs::model {
namespace {

constexpr int64_t kPoseEmbeddingSize = 6;  // a 6D rotation

}  // namespace

MlpShape ColourOffsetImpl::shape(int64_t feature_width, int64_t hidden_width) {
  return MlpShape{{feature_width, kPoseEmbeddingSize + 3},
                  {hidden_width, hidden_width, hidden_width},
                  3,
                  /*group_norm=*/true,
                  /*zero_output=*/true};
}

ColourOffsetImpl::ColourOffsetImpl(int64_t feature_width, int64_t hidden_width) {
  mlp_ = register_module("mlp", Mlp(shape(feature_width, hidden_width)));
}

at::Tensor ColourOffsetImpl::project_features(const at::Tensor& features) const { return mlp_->project(0, features); }

at::Tensor ColourOffsetImpl::forward(const at::Tensor& feature_projection, const at::Tensor& pose_embedding,
                                     const at::Tensor& normals) const {
  return mlp_->finish_from(feature_projection, 1, {pose_embedding, normals});
}

}  // namespace sfgs::model
