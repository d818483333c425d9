#pragma once
// The SFGS avatar: canonical Gaussians on the subdivided SMPL-X-layout mesh, a triplane + hexplane feature field with
// a learned per-channel gate (and dedicated face planes), MLP heads for position/scale/colour, the structure-aware
// position/scale offset (dominant-joint feature) and colour offset (skinning-weighted pose embedding + posed normal),
// the MANO hand residual, expression offsets and pose correctives, and linear blend skinning of means and covariances.
// Each module can be switched off for ablations; pose- and time-independent features are cached for inference.
// docs/avatar.md describes the architecture, the switches, the parameter count and what differs from the authors.
#include <optional>
#include <string>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/mano.h"
#include "body/parts.h"
#include "body/smplx.h"
#include "model/canonical_body.h"
#include "model/colour_offset.h"
#include "model/feature_field.h"
#include "model/hand_residual.h"
#include "model/heads.h"
#include "model/structure_offset.h"
#include "splat/splat.h"

namespace sfgs::model {

struct AvatarConfig {
  int64_t subdivision_levels = 2;       // midpoint subdivisions of the body mesh (SMPL-X: 167,390 points)
  int64_t plane_channels = 32;          // C per plane
  int64_t plane_resolution = 128;       // body triplane / hexplane spatial resolution
  int64_t time_resolution = 32;         // hexplane resolution along t
  int64_t face_plane_resolution = 256;  // dedicated face planes (over the face's own, much smaller, bounding box)
  int64_t hidden_width = 128;           // MLP width (a multiple of the GroupNorm groups, kMlpGroupNormGroups)
  int64_t joint_embedding_size = 16;
  int64_t num_betas = 10;              // at most the model's shape space
  int64_t num_expression_coeffs = 10;  // at most the model's expression space
  // false: the model's mean hand pose is added to AvatarPose's hand poses (SMPL-X's flat_hand_mean = False, the
  // convention of ExAvatar's and SFGS's fits); true: the hand poses are absolute.
  bool flat_hand_mean = false;
  // Ablation switches (the paper's table): each removes exactly its module, and its parameters.
  bool use_hexplane = true;
  bool use_structure_offset = true;
  bool use_color_offset = true;
  bool use_hand_residual = true;  // also needs MANO in the AvatarBody
  bool use_face_planes = true;
};

// Everything an avatar needs from a body model: SMPL-X layout, optionally MANO hands with their correspondence.
struct AvatarBody {
  body::SmplxModelData smplx;
  bool has_mano = false;
  body::ManoModelData mano_left, mano_right;  // defined when has_mano (the avatar repairs the left shapedirs)
  body::HandVertexIds hand_vertex_ids;        // SMPL-X vertex of each MANO vertex, when has_mano
  at::Tensor face_vertex_ids;                 // (K) SMPL-X vertices of the face region; undefined: from part labels

  // The built-in procedural body (with its MANO-layout hands).
  static AvatarBody procedural();
  // SMPL-X file plus, when given (may be empty), MANO left/right .npz and MANO_SMPLX_vertex_ids.npz (all three or
  // none), and the FLAME vertex ids .npy.
  static AvatarBody load(const std::string& smplx_path, const std::string& mano_left_path,
                         const std::string& mano_right_path, const std::string& hand_ids_path,
                         const std::string& face_ids_path);
};

// One frame's drive: SMPL-X parameters (axis-angle, batch 1, full hand poses) and the normalised time in [-1, 1].
// Undefined tensors are zeros, except that undefined hand poses also skip that hand's MANO residual (the sequence
// has no hand poses) and an undefined expression skips the expression blend shapes. Any floating dtype and device:
// they are moved to the avatar's. Every value must be finite (forward refuses NaN or Inf, naming the field); give
// them on the CPU to keep that check free of a device synchronisation.
struct AvatarPose {
  at::Tensor global_orient;    // (3)
  at::Tensor body_pose;        // (21, 3) or (63)
  at::Tensor jaw_pose;         // (3)
  at::Tensor left_eye_pose;    // (3)
  at::Tensor right_eye_pose;   // (3)
  at::Tensor left_hand_pose;   // (15, 3) or (45)
  at::Tensor right_hand_pose;  // (15, 3) or (45)
  at::Tensor expression;       // (E) (padded / truncated to num_expression_coeffs)
  at::Tensor transl;           // (3)
  double time = 0.0;           // normalised once per sequence to [-1, 1]
};

// The posed Gaussians ready for sfgs::render, plus what the regularisers need.
struct AvatarOutput {
  at::Tensor means;        // (N, 3) world
  at::Tensor covariances;  // (N, 6) world, packed (xx, xy, xz, yy, yz, zz)
  at::Tensor opacities;    // (N) constant ones (not learned)
  at::Tensor colours;      // (N, 3) in [0, 1]
  // Canonical quantities (before skinning) for regularisers and export.
  at::Tensor canonical_means;   // (N, 3): this frame's rest mesh plus every offset below
  at::Tensor log_scales;        // (N) isotropic log standard deviation (after the structure offset)
  at::Tensor mean_offset;       // (N, 3) from the feature head
  at::Tensor structure_offset;  // (N, 3) zeros when switched off
  at::Tensor scale_offset;      // (N) zeros when switched off
  at::Tensor colour_offset;     // (N, 3) zeros when switched off
  at::Tensor hand_residual;     // (N, 3) zeros off the hands or when switched off
  at::Tensor posed_vertices;    // (N, 3) the skinned mesh points without learned offsets (for geometry metrics)
};

// The posed Gaussians as the splatting op takes them.
Gaussians to_gaussians(const AvatarOutput& out);

class AvatarImpl : public torch::nn::Module {
 public:
  // betas: the subject's SMPL-X shape, (B) or (1, B). The module is built on the CPU in float32; move it with to().
  AvatarImpl(const AvatarBody& body, const at::Tensor& betas, AvatarConfig config = {});

  AvatarOutput forward(const AvatarPose& pose);

  // Pose- and time-independent features and canonical attributes computed once; forward then reuses them, and
  // with the hexplane also the time-dependent ones of the last time it saw. For inference only: forward refuses
  // the cache in training mode. Call after training (or after loading a checkpoint, or moving the module); any
  // parameter update invalidates the cache.
  void cache_static_features();
  void clear_cache();

  int64_t gaussian_count() const;
  const at::Tensor& part_labels() const;  // (N) uint8 body::BodyPart, on the module's device
  const at::Tensor& faces() const;        // (F, 3) int64 of the subdivided mesh (Laplacian, export), likewise
  const AvatarConfig& config() const;

 private:
  // What the fused feature determines: canonical attributes and the feature's share of the pose-driven MLPs.
  struct CanonicalAttributes {
    at::Tensor mean_offset;           // (N, 3)
    at::Tensor log_scales;            // (N) initial log-scale plus the head's offset
    at::Tensor colour_logits;         // (N, 3)
    at::Tensor structure_projection;  // (N, H), structure offset only
    at::Tensor colour_projection;     // (N, H), colour offset only
  };
  struct Cache {
    StaticFeatures features;
    std::optional<CanonicalAttributes> attributes;
    double time = 0.0;  // of the attributes (irrelevant without the hexplane)
  };
  CanonicalAttributes canonical_attributes(const StaticFeatures& features, double time) const;

  AvatarConfig config_;
  CanonicalBody body_{nullptr};
  FeatureField feature_field_{nullptr};
  CanonicalHeads heads_{nullptr};
  StructureOffset structure_offset_{nullptr};  // each of these null when switched off
  ColourOffset colour_offset_{nullptr};
  HandResidual hand_residual_{nullptr};
  at::Tensor opacities_;
  std::optional<Cache> cache_;
};
TORCH_MODULE(Avatar);

// The number of learned parameters of an avatar of this configuration, whatever its body (docs/avatar.md):
// has_mano says whether the body brings MANO hands, which the hand residual needs.
int64_t parameter_count(const AvatarConfig& config, bool has_mano);

}  // namespace sfgs::model
