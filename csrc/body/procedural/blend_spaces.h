#pragma once
// The procedural body's linear spaces: ten shape and ten expression directions (docs/body_models.md lists what
// each does) and the hand pose PCA basis with its mean pose. There are no pose correctives.
#include <array>
#include <cstdint>

#include <ATen/core/Tensor.h>

#include "body/procedural/body_cage.h"

namespace sfgs::body::procedural {

// Ten shape directions (columns of the v1.1 shape space), (V, 3, 10), for the template `p` (V, 3) with skinning
// weights `w` (V, 55) and regressed joints (55, 3).
at::Tensor shape_directions(const at::Tensor& p, const at::Tensor& w, const at::Tensor& joints);

// Ten expression directions (as many as SMPL-X's default num_expression_coeffs), (V, 3, 10), centred on the
// landmarks of the cage build `b`.
at::Tensor expression_directions(const at::Tensor& p, const at::Tensor& w, const CageBuild& b);

// Direction k becomes direction kMirroredExpressions[k] under mirroring.
inline constexpr std::array<int64_t, 10> kMirroredExpressions = {0, 1, 3, 2, 4, 5, 6, 7, 9, 8};

// Orthonormal (45, 45) PCA-style bases of the hand poses, curl, spread and thumb opposition first, and the
// relaxed mean poses (45); the right hand's are the left's mirror images.
struct HandPoseSpace {
  at::Tensor left_components, right_components, left_mean, right_mean;
};
HandPoseSpace hand_pose_space();

}  // namespace sfgs::body::procedural
