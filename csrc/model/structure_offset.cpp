#include "model/structure_offset.h"

#include <ATen/Functions.h>

#include "body/tensor_checks.h"
#include "ops/gathered_mlp/gathered_mlp.h"

namespace sfgs::model {
namespace {

constexpr int64_t kRotation6dSize = 6;

}  // namespace

MlpShape StructureOffsetImpl::shape(int64_t feature_width, int64_t hidden_width, int64_t embedding_size) {
  return MlpShape{{feature_width, kRotation6dSize + 3 + embedding_size},
                  {hidden_width, hidden_width},
                  3 + 1,
                  /*group_norm=*/false,
                  /*zero_output=*/true};
}

StructureOffsetImpl::StructureOffsetImpl(int64_t feature_width, int64_t hidden_width, int64_t embedding_size,
                                         const at::Tensor& canonical_joints, const at::Tensor& dominant_joints) {
  TORCH_CHECK(embedding_size > 0, "StructureOffset: the joint embedding size must be positive, got ", embedding_size);
  TORCH_CHECK(canonical_joints.defined() && canonical_joints.dim() == 2 && canonical_joints.size(1) == 3,
              "StructureOffset: canonical_joints must have shape (J, 3), got ", describe(canonical_joints));
  TORCH_CHECK(dominant_joints.defined() && dominant_joints.dim() == 1 && dominant_joints.scalar_type() == at::kLong,
              "StructureOffset: dominant_joints must be an int64 (N) tensor, got ", describe(dominant_joints));
  canonical_joints_ = register_buffer("canonical_joints", canonical_joints.to(at::kFloat));
  dominant_joints_ = register_buffer("dominant_joints", dominant_joints);
  // torch.nn.Embedding's initialisation.
  embedding_ = register_parameter("joint_embedding", at::randn({canonical_joints.size(0), embedding_size}));
  mlp_ = register_module("mlp", Mlp(shape(feature_width, hidden_width, embedding_size)));
  // forward's fused first layer is relu(...): a GroupNorm network would need its first activation instead.
  TORCH_CHECK(!mlp_->shape().group_norm, "StructureOffset: the network must have no GroupNorm");
}

at::Tensor StructureOffsetImpl::project_features(const at::Tensor& features) const {
  return mlp_->project(0, features);
}

at::Tensor StructureOffsetImpl::joint_features(const at::Tensor& joint_rotations_6d) const {
  const int64_t joints = canonical_joints_.size(0);
  check_tensor(joint_rotations_6d, "StructureOffset: joint_rotations_6d", {joints, kRotation6dSize},
               canonical_joints_.scalar_type(), canonical_joints_.device());
  return at::cat({joint_rotations_6d, canonical_joints_, embedding_}, 1);
}

StructureOffsetOutput StructureOffsetImpl::forward(const at::Tensor& feature_projection,
                                                   const at::Tensor& joint_rotations_6d) const {
  const at::Tensor joint_projection = mlp_->project(1, joint_features(joint_rotations_6d));
  // The first activation relu(feature projection + joint projection gathered by dominant joint) in one pass each way
  // (the network has no GroupNorm: shape()). Its backward reduces N rows' gradients onto the 55 joints: not as
  // index_select's backward would, piling N atomic additions onto 55 rows (tens of milliseconds on a GPU at 250k
  // points), but per block of rows in shared memory and over the blocks in a fixed order.
  const at::Tensor activation =
      gathered_mlp::gathered_first_layer(feature_projection, joint_projection, dominant_joints_);
  const at::Tensor out = mlp_->finish_activated(activation);
  return {out.narrow(1, 0, 3), out.select(1, 3)};
}

const at::Tensor& StructureOffsetImpl::dominant_joint_ids() const {
  if (!dominant_joints_int32_.defined() || dominant_joints_int32_.device() != dominant_joints_.device() ||
      dominant_joints_int32_.size(0) != dominant_joints_.size(0))
    dominant_joints_int32_ = dominant_joints_.to(at::kInt);
  return dominant_joints_int32_;
}

StructureOffsetOutput StructureOffsetImpl::forward_inference(const at::Tensor& feature_projection,
                                                             const at::Tensor& joint_rotations_6d) const {
  const at::Tensor joint_projection = mlp_->project(1, joint_features(joint_rotations_6d));
  const at::Tensor out =
      gathered_mlp::gathered_mlp(feature_projection, joint_projection, dominant_joint_ids(), mlp_->gathered_weights());
  return {out.narrow(1, 0, 3), out.select(1, 3)};
}

}  // namespace sfgs::model
