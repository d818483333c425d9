#pragma once
// The avatar's fixed body: the SMPL-X-layout model shaped by the subject's betas and midpoint-subdivided, one
// Gaussian per subdivided vertex. The canonical frame is the model's rest pose (the T-pose): there the model's
// expression blend shapes and pose correctives are defined, and linear blend skinning with the model's own
// transforms reproduces the posed body-model mesh exactly. Blend shapes and correctives act on the coarse
// vertices and are then subdivided (both are linear, so this equals subdividing every blend shape first, at a
// fraction of the memory: SMPL-X's 486 corrective directions on 167k points would take 1 GB).
#include <cstdint>
#include <vector>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/kinematics.h"
#include "body/skeleton.h"
#include "body/smplx.h"

namespace sfgs::model {

// The model shaped by a subject's betas, float64 on the CPU.
struct ShapedModel {
  at::Tensor betas;     // (S): the given betas truncated or zero-padded to S = min(num_betas, model's shape space)
  at::Tensor vertices;  // (V, 3) template plus shape blend shapes
  at::Tensor joints;    // (J, 3) regressed from them
};
// betas: (B) or (1, B), any floating dtype and device.
ShapedModel shape_model(const body::SmplxModelData& data, const at::Tensor& betas, int64_t num_betas);

class CanonicalBodyImpl : public torch::nn::Module {
 public:
  // shaped: `data` shaped by the subject's betas; num_expression_coeffs is capped by the model's expression space;
  // coarse_part_labels (V) uint8 body::BodyPart per model vertex.
  CanonicalBodyImpl(const body::SmplxModelData& data, const ShapedModel& shaped, int64_t subdivision_levels,
                    int64_t num_expression_coeffs, const at::Tensor& coarse_part_labels);

  int64_t point_count() const { return vertices_.size(0); }
  int64_t coarse_vertex_count() const { return coarse_vertex_count_; }
  int64_t expression_count() const { return expression_count_; }
  bool has_pose_correctives() const { return posedirs_.defined(); }

  const at::Tensor& vertices() const { return vertices_; }                      // (N, 3) shaped rest pose
  const at::Tensor& weights() const { return weights_; }                        // (N, J) skinning weights
  const at::Tensor& faces() const { return faces_; }                            // (F, 3) int64
  const at::Tensor& part_labels() const { return part_labels_; }                // (N) uint8 body::BodyPart
  const at::Tensor& dominant_joints() const { return dominant_joints_; }        // (N) int64
  const at::Tensor& initial_log_scales() const { return initial_log_scales_; }  // (N) from local edge lengths
  const at::Tensor& joints() const { return joints_; }                          // (J, 3) shaped rest joints
  const at::Tensor& hand_mean(body::Side side) const {                          // (15, 3) the model's mean hand pose
    return side == body::Side::kLeft ? hand_mean_left_ : hand_mean_right_;
  }

  // Per-vertex values of the coarse model (V, C) at the points (N, C): linear midpoint subdivision.
  at::Tensor subdivide(const at::Tensor& coarse) const;
  // The rest-pose displacement (V, 3) of the coarse vertices by the expression blend shapes (expression (E), may
  // be undefined) and the pose correctives of local rotations (J, 3, 3); undefined when neither applies.
  at::Tensor coarse_displacement(const at::Tensor& expression, const at::Tensor& rotations) const;
  // Rest joints (J, 3) for an expression (SMPL-X regresses joints from the expression-shaped mesh too).
  at::Tensor rest_joints(const at::Tensor& expression) const;
  // Forward kinematics of local rotations (J, 3, 3) about rest joints (J, 3), moved by translation (3).
  body::PosedSkeleton pose(const at::Tensor& rotations, const at::Tensor& rest_joints,
                           const at::Tensor& translation) const;
  // The points in SFGS's star pose (legs spread by kStarPoseHipAngle), where the feature planes are read.
  at::Tensor star_pose_vertices() const;

 private:
  int64_t coarse_vertex_count_ = 0;
  int64_t expression_count_ = 0;
  body::KinematicTree tree_{nullptr};
  at::Tensor vertices_, weights_, faces_, part_labels_, dominant_joints_, initial_log_scales_, joints_;
  at::Tensor hand_mean_left_, hand_mean_right_;
  at::Tensor expression_dirs_;        // (3 V, E)
  at::Tensor joint_expression_dirs_;  // (3 J, E)
  at::Tensor posedirs_;               // (9 (J - 1), 3 V), undefined for a model without correctives
  std::vector<at::Tensor> subdivision_edges_;
};
TORCH_MODULE(CanonicalBody);

}  // namespace sfgs::model
