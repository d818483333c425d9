#pragma once
// The MANO hand model as a LibTorch module, loaded from MANO_{RIGHT,LEFT} converted to .npz
// (python/tools/convert_mano_pkl.py) or from the procedural body's hands. Conventions follow vchoutas/smplx.
#include <cstdint>
#include <string>
#include <vector>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/skinned_mesh.h"

namespace sfgs::body {

// The arrays of a MANO model file, as float64 / int64 CPU tensors.
struct ManoModelData {
  at::Tensor v_template;         // (V, 3)
  at::Tensor faces;              // (F, 3) int64
  at::Tensor j_regressor;        // (16, V)
  at::Tensor weights;            // (V, 16)
  std::vector<int64_t> parents;  // (16)
  at::Tensor shapedirs;          // (V, 3, 10)
  at::Tensor posedirs;           // (V, 3, 135), undefined when the file's are all zero
  at::Tensor hands_components;   // (C, 45)
  at::Tensor hands_mean;         // (45)
  std::string source;

  static ManoModelData load(const std::string& path);
  // The keys of the official pickle after conversion (J_regressor dense, 'J' the rest joints).
  void save(const std::string& path, bool overwrite) const;
  void validate() const;
};

// The official MANO_LEFT carries MANO_RIGHT's shapedirs x components (vchoutas/smplx#48), so one beta vector
// does not give mirror-image hands. When the left model's shapedirs[:, 0, :] equal the right model's, they are
// negated and true is returned; correctly mirrored models (the procedural and Anny hands) are left alone.
bool repair_left_mano_shapedirs(ManoModelData& left, const ManoModelData& right);

struct ManoOptions {
  int64_t num_betas = 10;
  bool use_pca = true;
  int64_t num_pca_comps = 6;
  bool flat_hand_mean = false;  // false: the file's mean hand pose is added to hand_pose
  int64_t subdivision_levels = 0;
  at::ScalarType dtype = at::kFloat;
};

// Undefined inputs are zeros; defined ones share the batch size, the module's dtype and device.
struct ManoInput {
  at::Tensor betas;           // (B, num_betas)
  at::Tensor global_orient;   // (B, 3) rotation about the wrist
  at::Tensor hand_pose;       // (B, num_pca_comps) with use_pca, else (B, 45) or (B, 15, 3)
  at::Tensor transl;          // (B, 3)
  at::Tensor vertex_offsets;  // (V, 3) or (B, V, 3), added to the template
  at::Tensor joint_offsets;   // (16, 3) or (B, 16, 3), added to the regressed joints
  at::Tensor rotations;       // (B, 16, 3, 3) instead of global_orient and hand_pose
};

struct ManoOutput : BodyOutput {
  at::Tensor full_pose;  // (B, 16, 3) axis-angle after PCA and hand mean; undefined with rotations
};

class ManoImpl : public BodyModule {
 public:
  explicit ManoImpl(const ManoModelData& data, ManoOptions options = {});
  explicit ManoImpl(const std::string& path, ManoOptions options = {});

  ManoOutput forward(const ManoInput& input) const;

  const ManoOptions& options() const { return options_; }
  int64_t vertex_count() const { return mesh_->vertex_count(); }
  const at::Tensor& faces() const { return mesh_->faces(); }
  const at::Tensor& weights() const { return mesh_->weights(); }
  const SkinnedMesh& mesh() const { return mesh_; }
  at::ScalarType dtype() const { return mesh_->dtype(); }
  c10::Device device() const { return mesh_->device(); }

 private:
  ManoOptions options_;
  SkinnedMesh mesh_{nullptr};
  at::Tensor components_, mean_;
};
TORCH_MODULE(Mano);

}  // namespace sfgs::body
