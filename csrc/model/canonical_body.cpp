#include "model/canonical_body.h"

#include <algorithm>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/kinematics.h"
#include "body/mesh.h"
#include "body/parts.h"
#include "body/rotations.h"
#include "body/tensor_checks.h"
#include "model/constants.h"

namespace sfgs::model {
namespace {

// log(kInitialScaleEdgeFraction * mean length of the mesh edges at each vertex), float64.
at::Tensor initial_log_scales_from_edges(const at::Tensor& vertices, const at::Tensor& faces) {
  const int64_t n = vertices.size(0);
  const at::Tensor edges = body::mesh_edges(faces, n).edges;
  const at::Tensor a = edges.select(1, 0), b = edges.select(1, 1);
  const at::Tensor lengths = (vertices.index_select(0, a) - vertices.index_select(0, b)).pow(2).sum(1).sqrt();
  const at::Tensor ends = at::cat({a, b});
  const at::Tensor total = at::zeros({n}, vertices.options()).index_add_(0, ends, at::cat({lengths, lengths}));
  const at::Tensor count =
      at::zeros({n}, vertices.options()).index_add_(0, ends, at::ones({ends.size(0)}, vertices.options()));
  const at::Tensor mean = total / count.clamp_min(1);
  TORCH_CHECK(mean.min().item<double>() > 0,
              "Avatar: every point needs mesh edges of positive length to size its Gaussian; the subdivided mesh has "
              "an isolated vertex or coincident vertices");
  return (kInitialScaleEdgeFraction * mean).log();
}

// The subject's model as a skinned mesh: shape baked into the template, the expressions as its blend shapes.
body::SkinnedMeshData subject_mesh(const body::SmplxModelData& data, const ShapedModel& shaped,
                                   int64_t expression_count) {
  body::SkinnedMeshData mesh;
  mesh.v_template = shaped.vertices;
  mesh.faces = data.faces;
  mesh.j_regressor = data.j_regressor;
  mesh.weights = data.weights;
  mesh.parents = data.parents;
  mesh.blend_shapes = data.exprdirs.narrow(2, 0, expression_count);
  mesh.posedirs = data.posedirs;
  return mesh;
}

}  // namespace

ShapedModel shape_model(const body::SmplxModelData& data, const at::Tensor& betas, int64_t num_betas) {
  data.validate();
  TORCH_CHECK(num_betas >= 0, "Avatar: num_betas must be >= 0, got ", num_betas);
  TORCH_CHECK(betas.defined() && at::isFloatingType(betas.scalar_type()) &&
                  (betas.dim() == 1 || (betas.dim() == 2 && betas.size(0) == 1)),
              "Avatar: betas must be a floating (B) or (1, B) tensor, got ", describe(betas));
  const int64_t count = std::min(num_betas, data.shapedirs.size(2));
  const at::Tensor given = betas.flatten().to(at::kCPU, at::kDouble);
  ShapedModel shaped;
  shaped.betas = at::zeros({count}, at::kDouble);
  const int64_t used = std::min(count, given.size(0));
  shaped.betas.narrow(0, 0, used).copy_(given.narrow(0, 0, used));
  shaped.vertices = data.v_template + data.shapedirs.narrow(2, 0, count).matmul(shaped.betas);
  shaped.joints = data.j_regressor.matmul(shaped.vertices);
  return shaped;
}

CanonicalBodyImpl::CanonicalBodyImpl(const body::SmplxModelData& data, const ShapedModel& shaped,
                                     int64_t subdivision_levels, int64_t num_expression_coeffs,
                                     const at::Tensor& coarse_part_labels) {
  data.validate();
  const int64_t v = data.v_template.size(0);
  const int64_t j = static_cast<int64_t>(data.parents.size());
  TORCH_CHECK(subdivision_levels >= 0 && num_expression_coeffs >= 0,
              "Avatar: subdivision_levels and num_expression_coeffs must be >= 0, got ", subdivision_levels, " and ",
              num_expression_coeffs);
  TORCH_CHECK(shaped.vertices.defined() && shaped.vertices.sizes() == data.v_template.sizes() &&
                  shaped.joints.defined() && shaped.joints.sizes() == at::IntArrayRef({j, 3}),
              "CanonicalBody: the shaped model does not belong to '", data.source, "'");
  TORCH_CHECK(coarse_part_labels.defined() && coarse_part_labels.dim() == 1 && coarse_part_labels.size(0) == v &&
                  coarse_part_labels.scalar_type() == at::kByte,
              "Avatar: part labels must be a uint8 (", v, ") tensor, got ", describe(coarse_part_labels));
  const int64_t expressions = std::min(num_expression_coeffs, data.exprdirs.size(2));
  mesh_ = register_module("mesh",
                          body::SkinnedMesh(subject_mesh(data, shaped, expressions), at::kFloat, subdivision_levels));

  // Per-point data on the subdivided mesh, in float64 until stored. Every buffer is a copy of its own: Module::to()
  // converts buffers in place, and must not drag the caller's model data along.
  at::Tensor vertices = shaped.vertices, weights = data.weights, labels = coarse_part_labels, faces = data.faces;
  for (const body::MidpointSubdivision& step : body::midpoint_subdivisions(data.faces, v, subdivision_levels)) {
    vertices = step.interpolate(vertices);
    weights = step.interpolate(weights);
    labels = step.interpolate_labels(labels);
    faces = step.fine_faces();
  }
  vertices_ = register_buffer("vertices", body::buffer_copy(vertices, at::kFloat));
  faces_ = register_buffer("faces", body::buffer_copy(faces, at::kLong));
  part_labels_ = register_buffer("part_labels", body::buffer_copy(labels, at::kByte));
  dominant_joints_ = register_buffer("dominant_joints", body::dominant_joints(weights));
  initial_log_scales_ =
      register_buffer("initial_log_scales", initial_log_scales_from_edges(vertices, faces).to(at::kFloat));
  joints_ = register_buffer("joints", body::buffer_copy(shaped.joints, at::kFloat));
  hand_mean_left_ = register_buffer(
      "hand_mean_left", body::buffer_copy(data.hands_mean_left.reshape({body::kHandJointCount, 3}), at::kFloat));
  hand_mean_right_ = register_buffer(
      "hand_mean_right", body::buffer_copy(data.hands_mean_right.reshape({body::kHandJointCount, 3}), at::kFloat));
}

FrameBody CanonicalBodyImpl::pose(const at::Tensor& rotations, const at::Tensor& expression,
                                  const at::Tensor& translation, const at::Tensor& coarse_point_offsets) const {
  const auto options = vertices_.options();
  const at::Tensor coefficients =
      expression.defined() ? expression.unsqueeze(0) : at::zeros({1, expression_count()}, options);
  const body::BodyOutput out =
      mesh_->forward(coefficients, rotations.unsqueeze(0), translation.unsqueeze(0), at::Tensor(), at::Tensor(),
                     coarse_point_offsets, /*skin_vertices=*/false);
  FrameBody frame;
  frame.rest = out.rest_vertices.squeeze(0);
  frame.skinning_transforms = out.skinning_transforms.squeeze(0);
  frame.joints = out.joints.squeeze(0);
  if (out.point_offsets.defined()) frame.point_offsets = out.point_offsets.squeeze(0);
  return frame;
}

const skin::SkinningWeights& CanonicalBodyImpl::skinning_weights() const {
  const at::Tensor& dense = weights();
  if (!skinning_weights_.weights.defined() || skinning_weights_.weights.device() != dense.device() ||
      skinning_weights_.weights.scalar_type() != dense.scalar_type())
    skinning_weights_ = skin::SkinningWeights::from_dense(dense);
  return skinning_weights_;
}

at::Tensor CanonicalBodyImpl::star_pose_vertices() const {
  const auto options = vertices_.options();
  at::Tensor axis_angle = at::zeros({joint_count(), 3}, options);
  axis_angle[body::smplx_joint::kLeftHip][2] = kStarPoseHipAngle;
  axis_angle[body::smplx_joint::kRightHip][2] = -kStarPoseHipAngle;
  const at::Tensor transforms =
      pose(body::axis_angle_to_matrix(axis_angle), at::Tensor(), at::zeros({3}, options), at::Tensor())
          .skinning_transforms;
  // The rest mesh carried rigidly (no pose correctives): where SFGS reads its planes.
  return body::linear_blend_skinning(vertices_.unsqueeze(0), weights(), transforms.unsqueeze(0)).squeeze(0);
}

}  // namespace sfgs::model
