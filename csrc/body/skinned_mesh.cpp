#include "body/skinned_mesh.h"

#include <string>
#include <vector>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/mesh.h"
#include "body/tensor_checks.h"

namespace sfgs::body {
namespace {

void check_floating(const at::Tensor& t, const char* name, at::IntArrayRef shape) {
  TORCH_CHECK(t.defined() && t.sizes() == shape && at::isFloatingType(t.scalar_type()), "SkinnedMesh: ", name,
              " must be a floating tensor of shape ", shape, ", got ", describe(t));
}

}  // namespace

SkinnedMeshImpl::SkinnedMeshImpl(const SkinnedMeshData& data, at::ScalarType dtype, int64_t subdivision_levels) {
  TORCH_CHECK(at::isFloatingType(dtype), "SkinnedMesh: dtype must be floating, got ", dtype);
  TORCH_CHECK(data.v_template.defined() && data.v_template.dim() == 2 && data.v_template.size(1) == 3,
              "SkinnedMesh: v_template must have shape (V, 3), got ", describe(data.v_template));
  const int64_t v = data.v_template.size(0);
  const int64_t j = static_cast<int64_t>(data.parents.size());
  check_floating(data.v_template, "v_template", {v, 3});
  check_floating(data.j_regressor, "j_regressor", {j, v});
  check_floating(data.weights, "weights", {v, j});
  const int64_t k = data.blend_shapes.defined() ? data.blend_shapes.size(-1) : 0;
  if (data.blend_shapes.defined()) check_floating(data.blend_shapes, "blend_shapes", {v, 3, k});
  if (data.posedirs.defined()) check_floating(data.posedirs, "posedirs", {v, 3, 9 * (j - 1)});
  const at::Tensor faces = checked_faces(data.faces, v, "SkinnedMesh: faces");
  coarse_vertex_count_ = v;
  coefficient_count_ = k;
  tree_ = register_module("tree", KinematicTree(data.parents));

  // Regressor products in float64, so float32 models lose nothing to the order of summation.
  const auto host = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor template64 = data.v_template.to(host);
  const at::Tensor regressor64 = data.j_regressor.to(host);
  const at::Tensor blend64 = k > 0 ? data.blend_shapes.to(host) : at::zeros({v, 3, 0}, host);
  v_template_ = register_buffer("v_template", buffer_copy(template64, dtype));
  // Stored (K, 3 V): (B, K) x (K, 3 V) is the fastest orientation of the product, by a third with reference BLAS.
  blend_shapes_ = register_buffer("blend_shapes", buffer_copy(blend64.reshape({v * 3, k}).t(), dtype));
  j_regressor_ = register_buffer("j_regressor", buffer_copy(regressor64, dtype));
  joint_template_ = register_buffer("joint_template", buffer_copy(regressor64.matmul(template64), dtype));
  joint_blend_shapes_ =
      register_buffer("joint_blend_shapes",
                      buffer_copy(regressor64.matmul(blend64.reshape({v, 3 * k})).reshape({j * 3, k}).t(), dtype));
  if (data.posedirs.defined())
    posedirs_ =
        register_buffer("posedirs", buffer_copy(data.posedirs.to(host).reshape({v * 3, 9 * (j - 1)}).t(), dtype));

  at::Tensor weights = data.weights.to(host);
  faces_ = faces;
  int64_t level = 0;
  for (const MidpointSubdivision& step : midpoint_subdivisions(faces, v, subdivision_levels)) {
    weights = step.interpolate(weights);
    subdivision_edges_.push_back(register_buffer("subdivision_edges_" + std::to_string(level++), step.edges().clone()));
    faces_ = step.fine_faces();
  }
  weights_ = register_buffer("weights", buffer_copy(weights, dtype));
}

const at::Tensor& SkinnedMeshImpl::sparse_weights() const {
  if (!sparse_weights_.defined() || sparse_weights_.device() != weights_.device() ||
      sparse_weights_.scalar_type() != weights_.scalar_type())
    sparse_weights_ = sparse_skinning_weights(weights_);
  return sparse_weights_;
}

at::Tensor SkinnedMeshImpl::subdivide(const at::Tensor& coarse) const {
  TORCH_CHECK(coarse.defined() && (coarse.dim() == 2 || coarse.dim() == 3) &&
                  coarse.size(coarse.dim() - 2) == coarse_vertex_count_,
              "SkinnedMesh::subdivide: values must have shape (", coarse_vertex_count_, ", C) or (B, ",
              coarse_vertex_count_, ", C), got ", describe(coarse));
  at::Tensor fine = coarse;
  for (const at::Tensor& edges : subdivision_edges_) fine = append_edge_midpoints(fine, edges, coarse.dim() - 2);
  return fine;
}

BodyOutput SkinnedMeshImpl::forward(const at::Tensor& coefficients, const at::Tensor& rotations,
                                    const at::Tensor& translation, const at::Tensor& vertex_offsets,
                                    const at::Tensor& joint_offsets, const at::Tensor& point_offsets,
                                    bool skin_vertices) const {
  const int64_t j = joint_count(), v = coarse_vertex_count_;
  TORCH_CHECK(rotations.defined() && rotations.dim() == 4, "SkinnedMesh: rotations must have shape (B, ", j,
              ", 3, 3), got ", describe(rotations));
  const int64_t b = rotations.size(0);
  check_tensor(rotations, "SkinnedMesh: rotations", {b, j, 3, 3}, dtype(), device());
  check_tensor(coefficients, "SkinnedMesh: coefficients", {b, coefficient_count_}, dtype(), device());
  check_tensor(translation, "SkinnedMesh: translation", {b, 3}, dtype(), device());

  at::Tensor shaped = v_template_.expand({b, v, 3});
  at::Tensor rest_joints = joint_template_.expand({b, j, 3});
  if (coefficient_count_ > 0) {
    shaped = shaped + coefficients.matmul(blend_shapes_).view({b, v, 3});
    rest_joints = rest_joints + coefficients.matmul(joint_blend_shapes_).view({b, j, 3});
  }
  if (vertex_offsets.defined()) {
    check_tensor(vertex_offsets, "SkinnedMesh: vertex_offsets",
                 vertex_offsets.dim() == 2 ? std::vector<int64_t>{v, 3} : std::vector<int64_t>{b, v, 3}, dtype(),
                 device());
    shaped = shaped + vertex_offsets;
    rest_joints = rest_joints + j_regressor_.matmul(vertex_offsets);
  }
  if (joint_offsets.defined()) {
    check_tensor(joint_offsets, "SkinnedMesh: joint_offsets",
                 joint_offsets.dim() == 2 ? std::vector<int64_t>{j, 3} : std::vector<int64_t>{b, j, 3}, dtype(),
                 device());
    rest_joints = rest_joints + joint_offsets;
  }
  at::Tensor rest = shaped;
  if (posedirs_.defined()) rest = rest + pose_feature(rotations).matmul(posedirs_).view({b, v, 3});
  at::Tensor offsets;
  if (point_offsets.defined()) {
    check_tensor(point_offsets, "SkinnedMesh: point_offsets",
                 point_offsets.dim() == 2 ? std::vector<int64_t>{v, 3} : std::vector<int64_t>{b, v, 3}, dtype(),
                 device());
    // One subdivision pass for both: the offsets travel as three more channels of the rest mesh.
    const at::Tensor both = subdivide(at::cat({rest, point_offsets.expand({b, v, 3})}, 2));
    rest = both.narrow(2, 0, 3);
    offsets = both.narrow(2, 3, 3);
  } else {
    rest = subdivide(rest);
  }

  const PosedSkeleton skeleton = tree_->pose(rotations, rest_joints, translation);
  BodyOutput out;
  if (skin_vertices) out.vertices = linear_blend_skinning(rest, sparse_weights(), skeleton.skinning_transforms);
  out.joints = skeleton.joints;
  out.joint_transforms = skeleton.joint_transforms;
  out.skinning_transforms = skeleton.skinning_transforms;
  out.rest_vertices = rest;
  out.rest_joints = rest_joints;
  out.rotations = rotations;
  out.point_offsets = offsets;
  return out;
}

}  // namespace sfgs::body
