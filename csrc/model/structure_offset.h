#pragma once
// SFGS's structure-aware offset: every Gaussian is bound to its dominant joint (the argmax of its skinning
// weights); the joint feature [6D rotation of that joint in the current pose, its canonical position, a learnable
// embedding] concatenated with the fused feature goes through an MLP to a position offset (3) and a log-scale
// offset (1). A joint feature takes one of 55 values, so its share of the first layer is computed per joint and
// gathered per point, and the fused feature's share can be computed once per fused feature.
#include <cstdint>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "model/mlp.h"

namespace sfgs::model {

struct StructureOffsetOutput {
  at::Tensor mean_offset;       // (N, 3) in the canonical frame
  at::Tensor log_scale_offset;  // (N)
};

class StructureOffsetImpl : public torch::nn::Module {
 public:
  // canonical_joints (J, 3): rest joint positions; dominant_joints (N) int64 in [0, J).
  StructureOffsetImpl(int64_t feature_width, int64_t hidden_width, int64_t embedding_size,
                      const at::Tensor& canonical_joints, const at::Tensor& dominant_joints);

  // (N, feature_width) -> (N, hidden_width): the fused feature's share of the first layer.
  at::Tensor project_features(const at::Tensor& features) const;
  // joint_rotations_6d (J, 6): the current local joint rotations (body::matrix_to_rotation_6d).
  StructureOffsetOutput forward(const at::Tensor& feature_projection, const at::Tensor& joint_rotations_6d) const;
  // The same offsets for inference (no gradient) through the gathered MLP (gathered_mlp.h): on CUDA one fused
  // kernel that reads the feature projection once, kept in half precision by the caller.
  StructureOffsetOutput forward_inference(const at::Tensor& feature_projection,
                                          const at::Tensor& joint_rotations_6d) const;

  // The authors' fusion network: two hidden layers without normalisation.
  static MlpShape shape(int64_t feature_width, int64_t hidden_width, int64_t embedding_size);

 private:
  // (J, 6 + 3 + embedding): [6D rotation, canonical position, embedding] of every joint.
  at::Tensor joint_features(const at::Tensor& joint_rotations_6d) const;
  // dominant_joints_ as int32 for the fused kernel, converted once per device (not a buffer: checkpoints keep
  // their layout).
  const at::Tensor& dominant_joint_ids() const;

  at::Tensor canonical_joints_, dominant_joints_;
  mutable at::Tensor dominant_joints_int32_;
  at::Tensor embedding_;  // (J, embedding_size)
  Mlp mlp_{nullptr};      // groups: fused feature, joint feature
};
TORCH_MODULE(StructureOffset);

}  // namespace sfgs::model
