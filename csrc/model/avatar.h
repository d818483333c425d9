#pragma once
// The SFGS avatar: canonical Gaussians on the subdivided SMPL-X-layout mesh, a triplane + hexplane feature field with
// a learned per-channel gate (and dedicated face planes), MLP heads for position/scale/colour, the structure-aware
// position/scale offset (dominant-joint feature) and colour offset (skinning-weighted pose embedding + posed normal),
// the MANO hand residual, expression offsets and pose correctives, and linear blend skinning of means and covariances.
//
// A frame runs four typed stages (avatar.cpp): the frame's body (rotations, rest and posed mesh, skinning
// transforms), the canonical Gaussians (the rest mesh plus every learned offset), skinning into the world, and
// appearance (colours). The canonical attributes the fused feature determines come from the InferenceCache when one
// is kept (inference) and are computed otherwise. Each module can be switched off for ablations; a switched-off
// module costs nothing and its outputs are undefined. docs/avatar.md describes the architecture, the switches, the
// parameter count and what differs from the authors.
#include <memory>
#include <string>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/mano.h"
#include "body/mesh.h"
#include "body/parts.h"
#include "body/smplx.h"
#include "body/smplx_pose.h"
#include "model/canonical_body.h"
#include "model/colour_offset.h"
#include "model/feature_field.h"
#include "model/frame_time.h"
#include "model/hand_residual.h"
#include "model/heads.h"
#include "model/shading.h"
#include "model/structure_offset.h"
#include "ops/skin/skin.h"
#include "ops/splat/splat.h"
#include "model/constants.h"

namespace sfgs::mesh_propagation {
struct Plan;
}

namespace sfgs::model {

// What a pose's gradient flows through in forward_with_attributes. kWhole: everything the pose drives. kSkeleton: the
// body (correctives, joints, hand residual) and the skinning, with the pose-driven networks (structure and colour
// offsets) evaluated at the pose but held constant for the gradient (on CUDA the fused inference network): a fit
// that moves the body by centimetres and degrees is steered by the skeleton, and those networks' millimetres of detail
// cost about a third of a fit's evaluation (docs/performance.md, "Pose refinement and pose fitting").
enum class PoseGradient { kWhole, kSkeleton };

class InferenceCache;
struct CanonicalAttributes;
struct CanonicalGaussians;

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
  // false: the model's mean hand pose is added to the pose's hand poses (SMPL-X's flat_hand_mean = False, the
  // convention of ExAvatar's and SFGS's fits); true: the hand poses are absolute.
  bool flat_hand_mean = false;
  // Ablation switches (the paper's table): each removes exactly its module, and its parameters.
  bool use_hexplane = true;
  bool use_structure_offset = true;
  bool use_colour_offset = true;
  bool use_hand_residual = true;  // also needs MANO in the AvatarBody
  bool use_face_planes = true;
  // Whether frames without a time (new motions) get the colour offset. false: it is a residual of replay, like the
  // time branch: trained only in the steps that keep the frame's time, left out for a new motion, whose poses it
  // would extrapolate from the training poses' colours (it costs 0.4 dB on the novel-motion benchmark).
  // docs/avatar.md, "Time".
  bool colour_offset_on_new_motions = false;
  // Not in the paper: colours are albedo times one shared function of the posed world normal (shading.h), so light
  // fixed in the world is not baked into the colours of the training poses. docs/avatar.md, "Shading".
  bool use_shading = true;
  // The share of training steps that leave the time branch out (FrameTime without a value), so the avatar is as
  // good without a time (new motions) as with one (replay); 0 trains it only with times. docs/avatar.md, "Time".
  double time_dropout = 0.5;
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

// The posed Gaussians ready for sfgs::render, plus what the regularisers need. Outputs of switched-off modules
// (and the hand residual of a frame without hand poses) are undefined.
struct AvatarOutput {
  at::Tensor means;                // (N, 3) world
  at::Tensor covariances;          // (N, 6) world, packed (xx, xy, xz, yy, yz, zz)
  at::Tensor opacities;            // (N) constant ones (not learned)
  at::Tensor colours;              // (N, 3) non-negative: in [0, 1] without shading; shading may light them beyond 1
  at::Tensor albedo;               // (N, 3) in [0, 1]: the colours before shading (the colours themselves without it)
  at::Tensor skinning_transforms;  // (J, 4, 4) rest pose -> posed per joint: what skinned this frame's Gaussians
  at::Tensor posed_joints;         // (J, 3) world: the body model's joints in this pose
  // Canonical quantities (before skinning) for regularisers and export.
  at::Tensor canonical_means;   // (N, 3): this frame's rest mesh plus every offset below
  at::Tensor log_scales;        // (N) isotropic log standard deviation (after the structure offset)
  at::Tensor mean_offset;       // (N, 3) from the feature head
  at::Tensor structure_offset;  // (N, 3) structure offset
  at::Tensor scale_offset;      // (N) structure offset
  at::Tensor colour_offset;     // (N, 3) colour offset (undefined for a new motion, AvatarConfig)
  at::Tensor shading;           // (N, 3) the light factor colours were multiplied by (shading.h)
  at::Tensor hand_residual;     // (N, 3) hand residual; zero off the hands
  at::Tensor posed_vertices;    // (N, 3) the skinned mesh points without learned offsets (for geometry metrics)
  at::Tensor posed_normals;     // (N, 3) their unit vertex normals, world, no gradient (shading, observation)
};

// The posed Gaussians as the splatting op takes them.
Gaussians to_gaussians(const AvatarOutput& out);

class AvatarImpl : public torch::nn::Module {
 public:
  // betas: the subject's SMPL-X shape, (B) or (1, B). The module is built on the CPU in float32; move it with to().
  AvatarImpl(const AvatarBody& body, const at::Tensor& betas, AvatarConfig config = {});
  ~AvatarImpl() override;

  // One frame: an SMPL-X pose (one frame; any floating dtype and device, moved to the avatar's; every value must be
  // finite: give it on the CPU to keep that check free of a device synchronisation; undefined fields are at rest,
  // undefined hand poses also skip that hand's residual) and the frame's time: normalised to [-1, 1] for a frame
  // the training video covered, none for a new motion (frame_time.h).
  AvatarOutput forward(const body::SmplxPose& pose, FrameTime time);
  // forward without the check that every pose value is finite: for a caller that checked the pose itself before
  // moving it to the device (Animator: the check of device tensors is a host synchronisation a CUDA graph cannot
  // hold). A non-finite pose gives non-finite Gaussians.
  AvatarOutput forward_trusted_pose(const body::SmplxPose& pose, FrameTime time);
  // forward_trusted_pose with the time as a 0-dim tensor of the avatar's dtype and device (undefined: none), not
  // checked against [-1, 1]: for a caller that records the work as a CUDA graph and writes each replay's time into that
  // tensor (train/step_graphs.h, animate::Animator). With the inference cache, the time-dependent attributes are
  // computed from the cached static features every call (the cache keeps only host times' attributes).
  AvatarOutput forward_trusted_pose(const body::SmplxPose& pose, const at::Tensor& device_time);
  // What a frame at `time` takes from the canonical body before its pose (the planes' features, the heads, the
  // observation prior; from the cache when there is one), and forward_trusted_pose on such attributes: for a caller
  // that poses one frame many times (pose fitting, train/pose_fit.h) or keeps them in buffers a recorded CUDA graph
  // reads. `has_time`: whether they were made with a time (a replayed frame's appearance).
  CanonicalAttributes attributes(FrameTime time);
  AvatarOutput forward_with_attributes(const body::SmplxPose& pose, const CanonicalAttributes& attributes,
                                       bool has_time, PoseGradient gradient = PoseGradient::kWhole);

  // The observation record of training (observation_prior.h): per Gaussian, the share of training steps that saw it
  // front-facing, (N) on any device; undefined clears it. In eval mode an avatar with a record trusts each
  // Gaussian's learned colour and offsets in proportion to how well it was observed: the colours of surface the
  // video never or rarely showed come from the observed surface around it. Training mode ignores it.
  void set_observation(const at::Tensor& observed_fraction);
  const at::Tensor& observation() const { return observed_fraction_; }
  // The sampling record of training (sampling_filter.h): per Gaussian, the smallest world footprint of a pixel any
  // training view had of it, (N) on any device (kept on the CPU); undefined clears it. Renders that sample more
  // finely (animate::Animator) widen each Gaussian to the training's blur; the avatar's own forward ignores it.
  void set_sampling_record(const at::Tensor& record);
  const at::Tensor& sampling_record() const { return sampling_record_; }

  // Keeps the pose- and time-independent features and canonical attributes (and, with the hexplane, the
  // time-dependent ones of the last time it saw) for inference. forward refuses the cache in training mode. Call
  // after training (or after loading a checkpoint, or moving the module); any parameter update invalidates it.
  void cache_static_features();
  void clear_cache();
  bool has_cache() const { return cache_ != nullptr; }
  // Counts the cache's replacements (made, cleared): a recorded CUDA graph that read the cache is stale once it moves.
  int64_t cache_generation() const { return cache_generation_; }

  int64_t gaussian_count() const;
  // The expression coefficients a pose drives (num_expression_coeffs, at most the model's expression space); a pose's
  // expression of another length is cut or padded with zeros to it.
  int64_t expression_count() const;
  const at::Tensor& part_labels() const;  // (N) uint8 body::BodyPart, on the module's device
  const at::Tensor& faces() const;        // (F, 3) int64 of the subdivided mesh (Laplacian, export), likewise
  // The body model's vertex count V: the first V points of the subdivided mesh (of AvatarOutput::posed_vertices)
  // are the model's own vertices, where whole-body keypoints are defined (train/avatar_keypoints.h).
  int64_t model_vertex_count() const;
  // Each Gaussian's joint influences: forward skins canonical means with these and skinning_transforms.
  const skin::SkinningWeights& skinning_weights() const;
  // (9, 3) the shading's coefficients over ShadingImpl::basis (colours = albedo x max(0, basis(n) coefficients));
  // undefined without shading.
  at::Tensor shading_coefficients() const;
  // (15, 3) the body model's mean hand pose, which forward adds to given hand poses unless config().flat_hand_mean.
  const at::Tensor& hand_mean(body::Side side) const;
  const AvatarConfig& config() const;

 private:
  struct FramePose;
  FramePose frame_pose(const body::SmplxPose& pose) const;
  AvatarOutput posed(const body::SmplxPose& pose, FrameTime time, const at::Tensor& device_time);
  AvatarOutput posed_with(const body::SmplxPose& pose, const CanonicalAttributes& attributes, bool has_time,
                          PoseGradient gradient);
  CanonicalAttributes attributes_at(FrameTime time);
  CanonicalAttributes attributes_at(const at::Tensor& device_time);
  // The observation prior's plan on the module's device (made when first needed there).
  void plan_observation_prior();
  // time: 0-dim on the module's device, or undefined for none.
  CanonicalAttributes compute_attributes(const StaticFeatures& features, const at::Tensor& time) const;
  bool trusts_observation() const { return confidence_.defined() && !is_training(); }
  CanonicalAttributes with_observation_prior(CanonicalAttributes attributes) const;
  at::Tensor trusted(const at::Tensor& learned) const;  // scaled by the confidence when trusts_observation()
  CanonicalGaussians canonical_gaussians(const FramePose& frame, const FrameBody& body,
                                         const CanonicalAttributes& attributes, PoseGradient gradient) const;
  // Colours from the canonical attributes and the posed normals in `out` (and sets its colour offset and shading).
  at::Tensor appearance(const FramePose& frame, const CanonicalAttributes& attributes, bool replay,
                        PoseGradient gradient, AvatarOutput& out) const;

  AvatarConfig config_;
  CanonicalBody body_{nullptr};
  FeatureField feature_field_{nullptr};
  CanonicalHeads heads_{nullptr};
  StructureOffset structure_offset_{nullptr};  // each of these null when switched off
  ColourOffset colour_offset_{nullptr};
  Shading shading_{nullptr};
  HandResidual hand_residual_{nullptr};
  at::Tensor opacities_;
  at::Tensor observed_fraction_, confidence_;            // (N) and (N, 1) on the module's device, or undefined
  at::Tensor sampling_record_;                           // (N) float32 on the CPU, or undefined
  body::VertexNeighbours neighbours_;                    // of the mesh points, for the observation prior
  std::unique_ptr<mesh_propagation::Plan> propagation_;  // of confidence_, on its device; null until planned
  body::VertexFaces faces_around_;                       // of the mesh points on the CUDA device, for their normals
  std::unique_ptr<InferenceCache> cache_;
  int64_t cache_generation_ = 0;
};
TORCH_MODULE(Avatar);

// The number of learned parameters of an avatar of this configuration, whatever its body (docs/avatar.md):
// has_mano says whether the body brings MANO hands, which the hand residual needs.
int64_t parameter_count(const AvatarConfig& config, bool has_mano);

}  // namespace sfgs::model
