#pragma once
// The machinery SMPL-X and MANO share: a template mesh deformed by linear blend shapes, a joint regressor, pose
// correctives and linear blend skinning over a kinematic tree, optionally evaluated on a midpoint-subdivided mesh.
#include <cstdint>
#include <vector>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/kinematics.h"

namespace sfgs::body {

// A skinned model in model units (metres for SMPL-X and MANO), any floating dtype.
struct SkinnedMeshData {
  at::Tensor v_template;         // (V, 3)
  at::Tensor faces;              // (F, 3) integer
  at::Tensor j_regressor;        // (J, V)
  at::Tensor weights;            // (V, J)
  std::vector<int64_t> parents;  // (J), parents[0] = -1, parents[j] < j
  at::Tensor blend_shapes;       // (V, 3, K): one direction per coefficient (shape, then expression)
  at::Tensor posedirs;           // (V, 3, 9 (J - 1)), or undefined for a model without pose correctives
};

// Everything one evaluation produces. Vertices are at the output resolution (after subdivision); the transforms
// include the translation, so vertices == sum_j weights_ij * skinning_transforms_j * [rest_vertices_i; 1].
struct BodyOutput {
  at::Tensor vertices;             // (B, V', 3) posed (undefined when the forward was asked not to skin them)
  at::Tensor joints;               // (B, J, 3) posed
  at::Tensor joint_transforms;     // (B, J, 4, 4) world frame of each joint
  at::Tensor skinning_transforms;  // (B, J, 4, 4) rest pose -> posed, per joint
  at::Tensor rest_vertices;        // (B, V', 3) shaped, offset and pose-corrected, before skinning
  at::Tensor rest_joints;          // (B, J, 3) regressed from the shaped mesh, plus joint offsets
  at::Tensor rotations;            // (B, J, 3, 3) local joint rotations
  at::Tensor point_offsets;        // (B, V', 3) the forward's point_offsets subdivided; undefined without them
};

// Blend shapes, the regressor and pose correctives act on the V coarse vertices; the rest mesh is then subdivided
// `subdivision_levels` times by edge midpoints and skinned with the subdivided weights. Because blend shapes and
// correctives are linear, this equals evaluating a model whose every attribute was subdivided first (body/smplx.h
// `subdivide`) while storing only the fine weights. Constant products (regressor times template and blend shapes)
// are computed once, in float64, at construction.
class SkinnedMeshImpl : public BodyModule {
 public:
  SkinnedMeshImpl(const SkinnedMeshData& data, at::ScalarType dtype, int64_t subdivision_levels);

  // coefficients (B, K), local rotations (B, J, 3, 3), translation (B, 3); vertex_offsets ((V, 3) or (B, V, 3),
  // added to the template on the coarse mesh) and joint_offsets ((J, 3) or (B, J, 3), added to the regressed
  // joints) may be undefined. point_offsets ((V, 3) or (B, V, 3) on the coarse mesh, may be undefined) are not part
  // of the mesh: they are subdivided with it, in the same pass, and returned as BodyOutput::point_offsets (offsets
  // of points that ride on the mesh, e.g. the avatar's hand residual). All in the module's dtype and on its device.
  // skin_vertices false leaves BodyOutput::vertices undefined, for a caller that skins the rest vertices itself
  // (the avatar's fused skinning op).
  BodyOutput forward(const at::Tensor& coefficients, const at::Tensor& rotations, const at::Tensor& translation,
                     const at::Tensor& vertex_offsets, const at::Tensor& joint_offsets,
                     const at::Tensor& point_offsets = {}, bool skin_vertices = true) const;

  // Per-vertex values of the coarse mesh, (V, C) or (B, V, C), at the output vertices.
  at::Tensor subdivide(const at::Tensor& coarse) const;

  int64_t coarse_vertex_count() const { return coarse_vertex_count_; }
  int64_t vertex_count() const { return weights_.size(0); }  // output vertices
  int64_t joint_count() const { return tree_->size(); }
  int64_t coefficient_count() const { return coefficient_count_; }
  bool has_pose_correctives() const { return posedirs_.defined(); }
  const KinematicTree& tree() const { return tree_; }
  const at::Tensor& faces() const { return faces_; }      // (F', 3) int64 of the output mesh, CPU
  const at::Tensor& weights() const { return weights_; }  // (V', J) of the output mesh
  at::ScalarType dtype() const { return v_template_.scalar_type(); }
  c10::Device device() const { return v_template_.device(); }

 private:
  int64_t coarse_vertex_count_ = 0;
  int64_t coefficient_count_ = 0;
  KinematicTree tree_{nullptr};
  at::Tensor v_template_, blend_shapes_, j_regressor_, joint_template_, joint_blend_shapes_, posedirs_, weights_;
  // The same weights as sparse COO, what skinning multiplies with. Not a buffer: serialisation and Module::to
  // cannot handle sparse tensors, so it is derived again whenever weights_ moves or changes type.
  mutable at::Tensor sparse_weights_;
  const at::Tensor& sparse_weights() const;
  std::vector<at::Tensor> subdivision_edges_;
  at::Tensor faces_;
};
TORCH_MODULE(SkinnedMesh);

}  // namespace sfgs::body
