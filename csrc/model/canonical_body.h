#pragma once
// The avatar's body: the SMPL-X-layout model shaped once by the subject's betas — a body::SkinnedMesh whose
// template is the subject's shape and whose blend shapes are the expressions — midpoint-subdivided, with one
// Gaussian per subdivided vertex. The canonical frame is the model's rest pose (the T-pose): there the expression
// blend shapes and pose correctives are defined, and the mesh's own skinning transforms, applied to any canonical
// point (the fused skinning op, ops/skin/skin.h), carry the Gaussians into the frame. Beside the mesh it keeps what the
// avatar needs per point: part labels, dominant joints, initial scales and the star pose the feature planes are read
// in.
#include <cstdint>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/skeleton.h"
#include "body/skinned_mesh.h"
#include "body/smplx.h"
#include "ops/skin/skin.h"
#include "model/constants.h"

namespace sfgs::model {

// The model shaped by a subject's betas, float64 on the CPU.
struct ShapedModel {
  at::Tensor betas;     // (S): the given betas truncated or zero-padded to S = min(num_betas, model's shape space)
  at::Tensor vertices;  // (V, 3) template plus shape blend shapes
  at::Tensor joints;    // (J, 3) regressed from them
};
// betas: (B) or (1, B), any floating dtype and device.
ShapedModel shape_model(const body::SmplxModelData& data, const at::Tensor& betas, int64_t num_betas);

// The body of one frame, at the points (the subdivided mesh); the avatar skins the points itself.
struct FrameBody {
  at::Tensor rest;                 // (N, 3) the frame's rest mesh: subject shape, expression, pose correctives
  at::Tensor skinning_transforms;  // (J, 4, 4) rest pose -> posed, per joint (translation included)
  at::Tensor joints;               // (J, 3) posed
  at::Tensor point_offsets;        // (N, 3) the coarse point offsets given to pose(), subdivided; or undefined
};

class CanonicalBodyImpl : public torch::nn::Module {
 public:
  // shaped: `data` shaped by the subject's betas; num_expression_coeffs is capped by the model's expression space;
  // coarse_part_labels (V) uint8 body::BodyPart per model vertex.
  CanonicalBodyImpl(const body::SmplxModelData& data, const ShapedModel& shaped, int64_t subdivision_levels,
                    int64_t num_expression_coeffs, const at::Tensor& coarse_part_labels);

  // Local joint rotations (J, 3, 3), expression (E) or undefined (none), translation (3), and offsets (V, 3) of the
  // coarse vertices to carry to the points (or undefined), all in the module's dtype and on its device.
  FrameBody pose(const at::Tensor& rotations, const at::Tensor& expression, const at::Tensor& translation,
                 const at::Tensor& coarse_point_offsets) const;

  int64_t point_count() const { return vertices_.size(0); }
  int64_t coarse_vertex_count() const { return mesh_->coarse_vertex_count(); }
  int64_t expression_count() const { return mesh_->coefficient_count(); }
  int64_t joint_count() const { return mesh_->joint_count(); }

  const at::Tensor& vertices() const { return vertices_; }        // (N, 3) shaped rest pose
  const at::Tensor& weights() const { return mesh_->weights(); }  // (N, J) skinning weights
  // The same weights as each point's influences, for the fused skinning op; converted on first use after a move.
  const skin::SkinningWeights& skinning_weights() const;
  const at::Tensor& faces() const { return faces_; }                            // (F, 3) int64
  const at::Tensor& part_labels() const { return part_labels_; }                // (N) uint8 body::BodyPart
  const at::Tensor& dominant_joints() const { return dominant_joints_; }        // (N) int64
  const at::Tensor& initial_log_scales() const { return initial_log_scales_; }  // (N) from local edge lengths
  const at::Tensor& joints() const { return joints_; }                          // (J, 3) shaped rest joints
  const at::Tensor& hand_mean(body::Side side) const {                          // (15, 3) the model's mean hand pose
    return side == body::Side::kLeft ? hand_mean_left_ : hand_mean_right_;
  }
  // The points in SFGS's star pose (legs spread by kStarPoseHipAngle), where the feature planes are read.
  at::Tensor star_pose_vertices() const;

 private:
  body::SkinnedMesh mesh_{nullptr};
  mutable skin::SkinningWeights skinning_weights_;
  at::Tensor vertices_, faces_, part_labels_, dominant_joints_, initial_log_scales_, joints_;
  at::Tensor hand_mean_left_, hand_mean_right_;
};
TORCH_MODULE(CanonicalBody);

}  // namespace sfgs::model
