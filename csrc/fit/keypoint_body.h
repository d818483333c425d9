#pragma once
// The SMPL-X model evaluated only at the vertices the fit looks at (the keypoints' support and a sample of the
// surface for the silhouette): shape and expression blend shapes, pose correctives and skinning of a few hundred
// vertices instead of the whole mesh, so a step over a whole video costs milliseconds. The joints are those of the
// full model (the regressor is applied to the blend shapes once, in float64). Differentiable, any device.
#include <ATen/core/Tensor.h>

#include <cstdint>

#include "body/kinematics.h"
#include "body/smplx.h"

namespace sfgs::fit {

struct PosedPoints {
  at::Tensor points;           // (B, S, 3) the chosen vertices, posed
  at::Tensor joints;           // (B, 55, 3)
  at::Tensor joint_rotations;  // (B, 55, 3, 3) each joint's global rotation
};

class KeypointBody {
 public:
  // `vertex_ids` (S) int64 model vertices; the first `betas` shape and `expressions` expression directions.
  KeypointBody(const body::SmplxModelData& model, const at::Tensor& vertex_ids, int64_t betas, int64_t expressions,
               const at::TensorOptions& options);

  // betas (K) shared by every frame, expression (B, E), local joint rotations (B, 55, 3, 3), translation (B, 3).
  PosedPoints forward(const at::Tensor& betas, const at::Tensor& expression, const at::Tensor& rotations,
                      const at::Tensor& translation) const;

  // (B, 3) rest position of the pelvis (the centre of the global rotation) for the shape and expressions.
  at::Tensor rest_pelvis(const at::Tensor& betas, const at::Tensor& expression) const;

  int64_t point_count() const { return template_points_.size(0); }

 private:
  at::Tensor rest_joints(const at::Tensor& betas, const at::Tensor& expression) const;

  body::KinematicTree tree_{nullptr};
  at::Tensor template_points_, shape_points_, expression_points_, posedirs_points_, weights_;
  at::Tensor joint_template_, joint_shape_, joint_expression_;
};

}  // namespace sfgs::fit
