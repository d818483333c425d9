#include "model/canonical_body.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/mesh.h"
#include "body/parts.h"
#include "body/rotations.h"
#include "body/tensor_checks.h"
#include "common/constants.h"

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

}  // namespace

ShapedModel shape_model(const body::SmplxModelData& data, const at::Tensor& betas, int64_t num_betas) {
  data.validate();
  TORCH_CHECK(num_betas >= 0, "Avatar: num_betas must be >= 0, got ", num_betas);
  TORCH_CHECK(betas.defined() && at::isFloatingType(betas.scalar_type()) &&
                  (betas.dim() == 1 || (betas.dim() == 2 && betas.size(0) == 1)),
              "Avatar: betas must be a floating (B) or (1, B) tensor, got ", body::describe(betas));
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
  coarse_vertex_count_ = v;
  TORCH_CHECK(subdivision_levels >= 0 && num_expression_coeffs >= 0,
              "Avatar: subdivision_levels and num_expression_coeffs must be >= 0, got ", subdivision_levels, " and ",
              num_expression_coeffs);
  TORCH_CHECK(shaped.vertices.defined() && shaped.vertices.sizes() == data.v_template.sizes() &&
                  shaped.joints.defined() && shaped.joints.sizes() == at::IntArrayRef({j, 3}),
              "CanonicalBody: the shaped model does not belong to '", data.source, "'");
  TORCH_CHECK(coarse_part_labels.defined() && coarse_part_labels.dim() == 1 && coarse_part_labels.size(0) == v &&
                  coarse_part_labels.scalar_type() == at::kByte,
              "Avatar: part labels must be a uint8 (", v, ") tensor, got ", body::describe(coarse_part_labels));
  expression_count_ = std::min(num_expression_coeffs, data.exprdirs.size(2));
  const at::Tensor expression_dirs = data.exprdirs.narrow(2, 0, expression_count_);  // (V, 3, E)
  joints_ = register_buffer("joints", shaped.joints.to(at::kFloat));
  expression_dirs_ =
      register_buffer("expression_dirs", expression_dirs.reshape({v * 3, expression_count_}).to(at::kFloat));
  joint_expression_dirs_ = register_buffer("joint_expression_dirs",
                                           data.j_regressor.matmul(expression_dirs.reshape({v, 3 * expression_count_}))
                                               .reshape({j * 3, expression_count_})
                                               .to(at::kFloat));
  if (data.posedirs.defined())
    posedirs_ = register_buffer("posedirs", data.posedirs.reshape({v * 3, -1}).t().contiguous().to(at::kFloat));

  at::Tensor vertices = shaped.vertices, weights = data.weights, labels = coarse_part_labels, faces = data.faces;
  int64_t level = 0;
  for (const body::MidpointSubdivision& step : body::midpoint_subdivisions(data.faces, v, subdivision_levels)) {
    vertices = step.interpolate(vertices);
    weights = step.interpolate(weights);
    labels = step.interpolate_labels(labels);
    faces = step.fine_faces();
    subdivision_edges_.push_back(register_buffer("subdivision_edges_" + std::to_string(level++), step.edges()));
  }
  vertices_ = register_buffer("vertices", vertices.to(at::kFloat));
  weights_ = register_buffer("weights", weights.to(at::kFloat));
  faces_ = register_buffer("faces", faces);
  part_labels_ = register_buffer("part_labels", labels);
  dominant_joints_ = register_buffer("dominant_joints", body::dominant_joints(weights));
  initial_log_scales_ =
      register_buffer("initial_log_scales", initial_log_scales_from_edges(vertices, faces).to(at::kFloat));
  hand_mean_left_ =
      register_buffer("hand_mean_left", data.hands_mean_left.reshape({body::kHandJointCount, 3}).to(at::kFloat));
  hand_mean_right_ =
      register_buffer("hand_mean_right", data.hands_mean_right.reshape({body::kHandJointCount, 3}).to(at::kFloat));
  tree_ = register_module("tree", body::KinematicTree(data.parents));
}

at::Tensor CanonicalBodyImpl::subdivide(const at::Tensor& coarse) const {
  TORCH_CHECK(coarse.defined() && coarse.dim() == 2 && coarse.size(0) == coarse_vertex_count_,
              "CanonicalBody::subdivide: values must have shape (", coarse_vertex_count_, ", C), got ",
              body::describe(coarse));
  at::Tensor fine = coarse;
  for (const at::Tensor& edges : subdivision_edges_) fine = body::append_edge_midpoints(fine, edges, 0);
  return fine;
}

at::Tensor CanonicalBodyImpl::coarse_displacement(const at::Tensor& expression, const at::Tensor& rotations) const {
  at::Tensor displacement;
  if (expression.defined() && expression_count_ > 0)
    displacement = expression_dirs_.matmul(expression).view({coarse_vertex_count_, 3});
  if (posedirs_.defined()) {
    const at::Tensor correctives =
        body::pose_feature(rotations.unsqueeze(0)).matmul(posedirs_).view({coarse_vertex_count_, 3});
    displacement = displacement.defined() ? displacement + correctives : correctives;
  }
  return displacement;
}

at::Tensor CanonicalBodyImpl::rest_joints(const at::Tensor& expression) const {
  if (!expression.defined() || expression_count_ == 0) return joints_;
  return joints_ + joint_expression_dirs_.matmul(expression).view_as(joints_);
}

body::PosedSkeleton CanonicalBodyImpl::pose(const at::Tensor& rotations, const at::Tensor& rest_joints,
                                            const at::Tensor& translation) const {
  body::PosedSkeleton skeleton =
      tree_->pose(rotations.unsqueeze(0), rest_joints.unsqueeze(0), translation.unsqueeze(0));
  skeleton.joints = skeleton.joints.squeeze(0);
  skeleton.joint_transforms = skeleton.joint_transforms.squeeze(0);
  skeleton.skinning_transforms = skeleton.skinning_transforms.squeeze(0);
  return skeleton;
}

at::Tensor CanonicalBodyImpl::star_pose_vertices() const {
  const auto options = vertices_.options();
  at::Tensor axis_angle = at::zeros({tree_->size(), 3}, options);
  axis_angle[body::smplx_joint::kLeftHip][2] = kStarPoseHipAngle;
  axis_angle[body::smplx_joint::kRightHip][2] = -kStarPoseHipAngle;
  const body::PosedSkeleton skeleton = pose(body::axis_angle_to_matrix(axis_angle), joints_, at::zeros({3}, options));
  return body::linear_blend_skinning(vertices_.unsqueeze(0), weights_, skeleton.skinning_transforms.unsqueeze(0))
      .squeeze(0);
}

}  // namespace sfgs::model
