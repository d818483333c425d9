#pragma once
// The SMPL-X body model as a LibTorch module, loaded from the official SMPLX_{NEUTRAL,MALE,FEMALE}.npz (v1.1, and
// v1.0's 10 + 10 blend shapes) or from the built-in procedural body (body/procedural_body.h). The conventions are
// those of the vchoutas/smplx reference loader; docs/body_models.md lists them and what each input means.
#include <cstdint>
#include <string>
#include <vector>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/skinned_mesh.h"
#include "body/smplx_pose.h"

namespace sfgs::body {

// The arrays of an SMPL-X model file, as float64 / int64 CPU tensors.
struct SmplxModelData {
  at::Tensor v_template;              // (V, 3)
  at::Tensor faces;                   // (F, 3) int64
  at::Tensor j_regressor;             // (55, V)
  at::Tensor weights;                 // (V, 55)
  std::vector<int64_t> parents;       // (55), parents[0] = -1
  at::Tensor shapedirs;               // (V, 3, S): S = 300 (v1.1) or 10 (v1.0)
  at::Tensor exprdirs;                // (V, 3, E): E = 100 (v1.1) or 10 (v1.0)
  at::Tensor posedirs;                // (V, 3, 486), undefined when the file's are all zero
  at::Tensor hands_components_left;   // (C, 45) PCA components of the left hand pose, C <= 45
  at::Tensor hands_components_right;  // (C, 45)
  at::Tensor hands_mean_left;         // (45) mean hand pose (added unless flat_hand_mean)
  at::Tensor hands_mean_right;        // (45)
  at::Tensor uvs;                     // (T, 2) texture coordinates (v up), undefined if the file has none
  at::Tensor uv_faces;                // (F, 3) int64 texture-coordinate indices per face corner
  at::Tensor part_labels;             // (V) uint8 BodyPart labels, undefined unless the file carries them
  std::string source;                 // where it came from, for messages

  // Reads an .npz in the official layout (extra keys, including pickled ones, are ignored). Errors name the file,
  // the array and what was expected.
  static SmplxModelData load(const std::string& path);
  // Writes the official v1.1 layout (shapedirs padded to 300 + 100 columns, zero posedirs when there are none),
  // plus 'part_labels' when defined, so the reference Python loader reads the file too.
  void save(const std::string& path, bool overwrite) const;
  // Checks that every array has the shape the others imply; load() and the layer call it.
  void validate() const;
};

// Every attribute (template, weights, blend shapes, correctives, UVs across seams, part labels) subdivided
// `levels` times by edge midpoints (body/mesh.h); the regressor gets zero columns for the new vertices, so the
// joints do not change. Twice on SMPL-X (with ExAvatar's 6 mouth faces) gives ExAvatar's 167,390 points.
SmplxModelData subdivide(const SmplxModelData& data, int64_t levels);

struct SmplxOptions {
  int64_t num_betas = 10;              // at most the file's shape space (300 or 10); more is clamped, with a warning
  int64_t num_expression_coeffs = 10;  // at most the file's expression space (100 or 10)
  bool use_pca = true;                 // hand poses as PCA coefficients (else 45 axis-angle values per hand)
  int64_t num_pca_comps = 6;
  bool flat_hand_mean = false;     // false: the file's mean hand pose is added to the hand poses
  int64_t subdivision_levels = 0;  // output on the midpoint-subdivided mesh (see SkinnedMesh)
  at::ScalarType dtype = at::kFloat;
};

// The layer's input: a batch of poses (SmplxPose with leading dimension B; with use_pca its hand fields hold
// (B, num_pca_comps) PCA coefficients) and what only the layer takes. Any input may be left undefined (zeros).
// Defined ones share the batch size B, the module's dtype and device. Poses are axis-angle; (B, 3 n) and (B, n, 3)
// are both accepted.
struct SmplxInput {
  SmplxPose pose;
  at::Tensor betas;           // (B, num_betas)
  at::Tensor vertex_offsets;  // (V, 3) or (B, V, 3) on the file's mesh, added to the template (ExAvatar's face offsets)
  at::Tensor joint_offsets;   // (55, 3) or (B, 55, 3), added to the regressed joints (ExAvatar's joint offsets)
  // (B, 55, 3, 3) local joint rotations instead of the pose's axis-angle rotations (which must then be undefined),
  // e.g. from rotation_6d_to_matrix; hand PCA and the hand mean do not apply.
  at::Tensor rotations;
};

struct SmplxOutput : BodyOutput {
  at::Tensor full_pose;  // (B, 55, 3) axis-angle of every joint after hand PCA and hand mean; undefined with rotations
};

class SmplxImpl : public BodyModule {
 public:
  explicit SmplxImpl(const SmplxModelData& data, SmplxOptions options = {});
  explicit SmplxImpl(const std::string& path, SmplxOptions options = {});

  SmplxOutput forward(const SmplxInput& input) const;
  // The (B, 55, 3) axis-angle pose the axis-angle inputs describe (hand PCA and mean applied), for batch size B.
  at::Tensor full_pose(const SmplxInput& input, int64_t batch) const;

  const SmplxOptions& options() const { return options_; }  // with num_betas / num_expression_coeffs as clamped
  int64_t vertex_count() const { return mesh_->vertex_count(); }
  const at::Tensor& faces() const { return mesh_->faces(); }      // (F', 3) int64, CPU
  const at::Tensor& weights() const { return mesh_->weights(); }  // (V', 55)
  const at::Tensor& uvs() const { return uvs_; }                  // (T', 2) CPU float64, or undefined
  const at::Tensor& uv_faces() const { return uv_faces_; }        // (F', 3) int64 CPU, or undefined
  const at::Tensor& part_labels() const { return part_labels_; }  // (V') uint8 CPU, or undefined
  const SkinnedMesh& mesh() const { return mesh_; }
  at::ScalarType dtype() const { return mesh_->dtype(); }
  c10::Device device() const { return mesh_->device(); }

 private:
  SmplxOptions options_;
  SkinnedMesh mesh_{nullptr};
  at::Tensor hands_left_, hands_right_;            // (components, 45) or (45, 45) identity without PCA
  at::Tensor hands_mean_left_, hands_mean_right_;  // (45)
  at::Tensor uvs_, uv_faces_, part_labels_;
};
TORCH_MODULE(Smplx);

}  // namespace sfgs::body
