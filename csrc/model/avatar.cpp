#include "model/avatar.h"

#include <cmath>
#include <optional>
#include <string>
#include <utility>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "body/mesh.h"
#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "model/constants.h"
#include "common/matmul_precision.h"
#include "common/stage_timer.h"
#include "model/inference_cache.h"
#include "model/observation_prior.h"
#include "ops/skin/skin.h"

namespace sfgs::model {

// The frame's pose in the avatar's dtype and on its device, as the stages use it.
struct AvatarImpl::FramePose {
  at::Tensor rotations;              // (J, 3, 3) local rotations of every joint (hand means applied)
  at::Tensor rotations_6d;           // (J, 6) the same, for the pose-driven networks
  at::Tensor left_hand, right_hand;  // (15, 3) as applied; undefined where the pose gives no hand pose
  at::Tensor expression;             // (E) padded or truncated to the model's, or undefined
  at::Tensor translation;            // (3)
};

// The Gaussians in the canonical frame: the frame's rest mesh plus every learned offset.
struct CanonicalGaussians {
  at::Tensor means;             // (N, 3)
  at::Tensor log_scales;        // (N)
  at::Tensor structure_offset;  // (N, 3), undefined when switched off
  at::Tensor scale_offset;      // (N), likewise
};

namespace {

void check_frame_time(FrameTime time) {
  TORCH_CHECK(!time || (std::isfinite(*time) && *time >= -1.0 && *time <= 1.0),
              "Avatar: time must be normalised to [-1, 1] (once per sequence), got ", *time);
}

using body::BodyPart;

void check_config(const AvatarConfig& c) {
  TORCH_CHECK(c.subdivision_levels >= 0, "Avatar: subdivision_levels must be >= 0, got ", c.subdivision_levels);
  TORCH_CHECK(c.plane_channels > 0, "Avatar: plane_channels must be positive, got ", c.plane_channels);
  TORCH_CHECK(c.plane_resolution > 1 && c.time_resolution > 1 && c.face_plane_resolution > 1,
              "Avatar: plane_resolution, time_resolution and face_plane_resolution must be at least 2, got ",
              c.plane_resolution, ", ", c.time_resolution, " and ", c.face_plane_resolution);
  TORCH_CHECK(c.hidden_width > 0 && c.hidden_width % kMlpGroupNormGroups == 0,
              "Avatar: hidden_width must be a positive multiple of ", kMlpGroupNormGroups, " (GroupNorm groups), got ",
              c.hidden_width);
  TORCH_CHECK(c.joint_embedding_size > 0, "Avatar: joint_embedding_size must be positive, got ",
              c.joint_embedding_size);
  TORCH_CHECK(c.time_dropout >= 0 && c.time_dropout <= 1, "Avatar: time_dropout must be in [0, 1], got ",
              c.time_dropout);
  TORCH_CHECK(c.num_betas >= 0 && c.num_expression_coeffs >= 0,
              "Avatar: num_betas and num_expression_coeffs must be >= 0, got ", c.num_betas, " and ",
              c.num_expression_coeffs);
}

FeatureFieldOptions field_options(const AvatarConfig& c) {
  FeatureFieldOptions field;
  field.channels = c.plane_channels;
  field.resolution = c.plane_resolution;
  field.time_resolution = c.time_resolution;
  field.face_resolution = c.face_plane_resolution;
  field.use_hexplane = c.use_hexplane;
  field.use_face_planes = c.use_face_planes;
  return field;
}

// Labels per model vertex: the model's own (or those its skinning weights imply), with the face and hand regions
// replaced by the id files' where the body brings them.
at::Tensor coarse_part_labels(const AvatarBody& b) {
  const body::SmplxModelData& d = b.smplx;
  at::Tensor labels = d.part_labels.defined() ? d.part_labels.clone() : body::part_labels_from_weights(d.weights);
  const auto relabel = [&](const at::Tensor& ids, BodyPart part) {
    const auto value = static_cast<int64_t>(part);
    labels.masked_fill_(labels == value, static_cast<int64_t>(BodyPart::kBody));
    labels.index_fill_(0, ids.to(at::kCPU, at::kLong), value);
  };
  if (b.face_vertex_ids.defined()) relabel(b.face_vertex_ids, BodyPart::kFace);
  if (b.has_mano) {
    relabel(b.hand_vertex_ids.left, BodyPart::kLeftHand);
    relabel(b.hand_vertex_ids.right, BodyPart::kRightHand);
  }
  return labels;
}

// Points (N, 3) mapped affinely, per axis, from their bounding box onto [-1, 1]^3.
at::Tensor normalise_to_box(const at::Tensor& points, const char* what) {
  const at::Tensor low = std::get<0>(points.min(0)), high = std::get<0>(points.max(0));
  const at::Tensor half = (high - low) / 2;
  TORCH_CHECK(half.min().item<double>() > 0, "Avatar: the ", what, " points span no volume (bounding box ", low, " to ",
              high, ")");
  return (points - (low + half)) / half;
}

// An axis-angle pose of `joints` joints as (joints, 3) in `options`, zeros when undefined.
at::Tensor joint_pose(const at::Tensor& pose, int64_t joints, const char* name, const at::TensorOptions& options) {
  if (!pose.defined()) return at::zeros({joints, 3}, options);
  TORCH_CHECK(at::isFloatingType(pose.scalar_type()) && pose.numel() == 3 * joints &&
                  (pose.dim() == 1 || (pose.dim() == 2 && pose.size(0) == joints)),
              "Avatar: pose.", name, " must be a floating (", joints, ", 3) or (", 3 * joints, ") tensor, got ",
              describe(pose));
  return pose.reshape({joints, 3}).to(options);
}

at::Tensor vector_input(const at::Tensor& t, const char* name, const at::TensorOptions& options) {
  TORCH_CHECK(at::isFloatingType(t.scalar_type()) && (t.dim() == 1 || (t.dim() == 2 && t.size(0) == 1)),
              "Avatar: pose.", name, " must be a floating (n) or (1, n) tensor, got ", describe(t));
  return t.flatten().to(options);
}

}  // namespace

AvatarImpl::AvatarImpl(const AvatarBody& b, const at::Tensor& betas, AvatarConfig config) : config_(config) {
  check_config(config_);
  const ShapedModel shaped = shape_model(b.smplx, betas, config_.num_betas);
  body_ = register_module("body", CanonicalBody(b.smplx, shaped, config_.subdivision_levels,
                                                config_.num_expression_coeffs, coarse_part_labels(b)));
  const int64_t n = body_->point_count();

  const at::Tensor star = body_->star_pose_vertices();
  const at::Tensor face_points = (body_->part_labels() == static_cast<int64_t>(BodyPart::kFace)).nonzero().flatten();
  const at::Tensor face_coordinates = face_points.size(0) > 0
                                          ? normalise_to_box(star.index_select(0, face_points), "face")
                                          : at::zeros({0, 3}, star.options());
  feature_field_ = register_module("feature_field", FeatureField(field_options(config_), normalise_to_box(star, "body"),
                                                                 face_points, face_coordinates));
  const int64_t width = feature_field_->width();
  heads_ = register_module("heads", CanonicalHeads(width, config_.hidden_width));
  if (config_.use_structure_offset)
    structure_offset_ =
        register_module("structure_offset", StructureOffset(width, config_.hidden_width, config_.joint_embedding_size,
                                                            body_->joints(), body_->dominant_joints()));
  if (config_.use_colour_offset)
    colour_offset_ = register_module("colour_offset", ColourOffset(width, config_.hidden_width));
  if (config_.use_shading) shading_ = register_module("shading", Shading());
  if (config_.use_hand_residual && b.has_mano) {
    body::ManoModelData left = b.mano_left;
    body::repair_left_mano_shapedirs(left, b.mano_right);
    hand_residual_ = register_module(
        "hand_residual", HandResidual(b.smplx, shaped.vertices, shaped.joints, left, b.mano_right, b.hand_vertex_ids));
  }
  opacities_ = register_buffer("opacities", at::ones({n}));
}

AvatarImpl::~AvatarImpl() = default;

AvatarOutput AvatarImpl::forward(const body::SmplxPose& pose, FrameTime time) {
  const std::string non_finite = pose.non_finite();
  TORCH_CHECK(non_finite.empty(), "Avatar: pose.", non_finite);
  return forward_trusted_pose(pose, time);
}

AvatarOutput AvatarImpl::forward_trusted_pose(const body::SmplxPose& pose, FrameTime time) {
  check_frame_time(time);
  return posed(pose, time, at::Tensor());
}

AvatarOutput AvatarImpl::forward_trusted_pose(const body::SmplxPose& pose, const at::Tensor& device_time) {
  const at::Tensor& reference = body_->vertices();
  TORCH_CHECK(
      !device_time.defined() || (device_time.dim() == 0 && device_time.scalar_type() == reference.scalar_type() &&
                                 device_time.device() == reference.device()),
      "Avatar: a device time must be a 0-dim ", reference.scalar_type(), " tensor on ", reference.device(), ", got ",
      describe(device_time));
  return posed(pose, std::nullopt, device_time);
}

CanonicalAttributes AvatarImpl::attributes(FrameTime time) {
  check_frame_time(time);
  std::optional<Tf32MatmulScope> products;
  if (!at::GradMode::is_enabled() && body_->vertices().is_cuda()) products.emplace(true);
  plan_observation_prior();
  return attributes_at(time);
}

AvatarOutput AvatarImpl::forward_with_attributes(const body::SmplxPose& pose, const CanonicalAttributes& attributes,
                                                 bool has_time, PoseGradient gradient) {
  TORCH_CHECK(attributes.mean_offset.defined() && attributes.log_scales.defined() &&
                  attributes.colour_logits.defined() && attributes.mean_offset.size(0) == gaussian_count(),
              "Avatar: forward_with_attributes takes the attributes of this avatar (", gaussian_count(),
              " Gaussians), made by attributes()");
  std::optional<Tf32MatmulScope> products;
  if (!at::GradMode::is_enabled() && body_->vertices().is_cuda()) products.emplace(true);
  return posed_with(pose, attributes, has_time, gradient);
}

// One of host_time and device_time at most; device_time bypasses the cache.
AvatarOutput AvatarImpl::posed(const body::SmplxPose& pose, FrameTime host_time, const at::Tensor& device_time) {
  const bool has_time = host_time.has_value() || device_time.defined();
  // An inference frame on CUDA: its networks (the time path's and the colour offset's) in TF32.
  std::optional<Tf32MatmulScope> products;
  if (!at::GradMode::is_enabled() && body_->vertices().is_cuda()) products.emplace(true);
  plan_observation_prior();
  CanonicalAttributes attributes;
  {
    const StageScope stage("avatar: canonical attributes (planes, heads)");
    attributes = device_time.defined() ? attributes_at(device_time) : attributes_at(host_time);
  }
  return posed_with(pose, attributes, has_time, PoseGradient::kWhole);
}

AvatarOutput AvatarImpl::posed_with(const body::SmplxPose& pose, const CanonicalAttributes& attributes, bool has_time,
                                    PoseGradient gradient) {
  FramePose frame;
  at::Tensor coarse_residual;
  {
    const StageScope stage("avatar: pose and hand residual");
    frame = frame_pose(pose);
    if (hand_residual_) coarse_residual = hand_residual_->forward(frame.left_hand, frame.right_hand, frame.rotations);
  }
  FrameBody body;
  {
    const StageScope stage("avatar: body (correctives, subdivision, joints)");
    body = body_->pose(frame.rotations, frame.expression, frame.translation, coarse_residual);
  }
  CanonicalGaussians canonical;
  {
    const StageScope stage("avatar: structure offset");
    canonical = canonical_gaussians(frame, body, attributes, gradient);
  }

  AvatarOutput out;
  {
    // Skinning: the body model's own transforms carry every Gaussian, its mean and its covariance, and the rest
    // mesh.
    const StageScope stage("avatar: skinning");
    const skin::SkinnedGaussians skinned = skin::skin_gaussians(body_->skinning_weights(), body.skinning_transforms,
                                                                canonical.means, canonical.log_scales, body.rest);
    out.means = skinned.means;
    out.covariances = skinned.covariances;
    out.posed_vertices = skinned.posed_rest;
    out.skinning_transforms = body.skinning_transforms;
    out.posed_joints = body.joints;
  }
  out.opacities = opacities_;
  out.canonical_means = canonical.means;
  out.log_scales = canonical.log_scales;
  out.mean_offset = attributes.mean_offset;
  out.structure_offset = canonical.structure_offset;
  out.scale_offset = canonical.scale_offset;
  out.hand_residual = body.point_offsets;
  {
    // The body-model surface's orientation: smooth, free of the learned offsets' noise, and no gradient.
    const StageScope stage("avatar: normals");
    at::NoGradGuard no_grad;
    const at::Tensor& faces = body_->faces();
    // The faces around each point, made once per device: the fused normals then sum in a fixed order.
    if (!faces.is_cuda())
      faces_around_ = body::VertexFaces();  // the CPU reference needs none
    else if (!faces_around_.offsets.defined() || faces_around_.offsets.device() != faces.device())
      faces_around_ = body::vertex_faces(faces, out.posed_vertices.size(0));
    out.posed_normals =
        body::vertex_normals(out.posed_vertices.detach(), faces, faces.is_cuda() ? faces_around_ : body::VertexFaces());
  }
  const StageScope stage("avatar: appearance");
  out.colours = appearance(frame, attributes, has_time, gradient, out);
  return out;
}

AvatarImpl::FramePose AvatarImpl::frame_pose(const body::SmplxPose& pose) const {
  const auto options = body_->vertices().options();
  FramePose frame;
  const auto hand = [&](const at::Tensor& given, const char* name, body::Side side) {
    const at::Tensor h = joint_pose(given, body::kHandJointCount, name, options);
    return config_.flat_hand_mean ? h : h + body_->hand_mean(side);
  };
  const at::Tensor left = hand(pose.left_hand_pose, "left_hand_pose", body::Side::kLeft);
  const at::Tensor right = hand(pose.right_hand_pose, "right_hand_pose", body::Side::kRight);
  if (pose.left_hand_pose.defined()) frame.left_hand = left;
  if (pose.right_hand_pose.defined()) frame.right_hand = right;
  frame.rotations = body::axis_angle_to_matrix(
      at::cat({joint_pose(pose.global_orient, 1, "global_orient", options),
               joint_pose(pose.body_pose, body::kSmplxBodyJointCount, "body_pose", options),
               joint_pose(pose.jaw_pose, 1, "jaw_pose", options), joint_pose(pose.leye_pose, 1, "leye_pose", options),
               joint_pose(pose.reye_pose, 1, "reye_pose", options), left, right}));
  frame.rotations_6d = body::matrix_to_rotation_6d(frame.rotations);
  if (pose.expression.defined() && body_->expression_count() > 0) {
    const at::Tensor given = vector_input(pose.expression, "expression", options);
    const int64_t used = std::min(given.size(0), body_->expression_count());
    frame.expression = at::constant_pad_nd(given.narrow(0, 0, used), {0, body_->expression_count() - used});
  }
  frame.translation = at::zeros({3}, options);
  if (pose.transl.defined()) {
    frame.translation = vector_input(pose.transl, "transl", options);
    TORCH_CHECK(frame.translation.size(0) == 3, "Avatar: pose.transl must have 3 values, got ",
                frame.translation.size(0));
  }
  return frame;
}

CanonicalAttributes AvatarImpl::compute_attributes(const StaticFeatures& features, const at::Tensor& time) const {
  const at::Tensor fused = feature_field_->fuse(features, time);
  const CanonicalHeadOutput heads = heads_->forward(fused);
  CanonicalAttributes a;
  a.mean_offset = heads.mean_offset;
  a.log_scales = body_->initial_log_scales() + heads.log_scale_offset;
  a.colour_logits = heads.colour_logits;
  if (structure_offset_) a.structure_projection = structure_offset_->project_features(fused);
  if (colour_offset_) a.colour_projection = colour_offset_->project_features(fused);
  return trusts_observation() ? with_observation_prior(std::move(a)) : a;
}

CanonicalAttributes AvatarImpl::with_observation_prior(CanonicalAttributes a) const {
  const at::Tensor initial = body_->initial_log_scales();
  a.colour_logits = propagate_from_observed(a.colour_logits, *propagation_);
  a.mean_offset = trusted(a.mean_offset);
  a.log_scales = initial + trusted((a.log_scales - initial).unsqueeze(1)).squeeze(1);
  return a;
}

at::Tensor AvatarImpl::trusted(const at::Tensor& learned) const {
  return trusts_observation() && learned.defined() ? learned * confidence_ : learned;
}

void AvatarImpl::set_observation(const at::Tensor& observed_fraction) {
  clear_cache();
  propagation_.reset();
  if (!observed_fraction.defined()) {
    observed_fraction_ = confidence_ = at::Tensor();
    return;
  }
  const int64_t n = gaussian_count();
  TORCH_CHECK(observed_fraction.dim() == 1 && observed_fraction.size(0) == n &&
                  at::isFloatingType(observed_fraction.scalar_type()),
              "Avatar: the observation record must be a floating (", n, ") tensor, got ", describe(observed_fraction));
  const auto options = body_->vertices().options();
  observed_fraction_ = observed_fraction.detach().to(options);
  TORCH_CHECK(observed_fraction_.isfinite().all().item<bool>() && observed_fraction_.min().item<double>() >= 0,
              "Avatar: the observation record must be finite and non-negative");
  confidence_ = observation_confidence(observed_fraction_).unsqueeze(1);
  if (!neighbours_.indices.defined()) neighbours_ = body::vertex_neighbours(body_->faces().cpu(), n);
}

void AvatarImpl::set_sampling_record(const at::Tensor& record) {
  if (!record.defined()) {
    sampling_record_ = at::Tensor();
    return;
  }
  const int64_t n = gaussian_count();
  TORCH_CHECK(record.dim() == 1 && record.size(0) == n && at::isFloatingType(record.scalar_type()),
              "Avatar: the sampling record must be a floating (", n, ") tensor, got ", describe(record));
  const at::Tensor r = record.detach().to(at::kCPU, at::kFloat).contiguous();
  TORCH_CHECK(r.isfinite().all().item<bool>() && r.min().item<double>() >= 0,
              "Avatar: the sampling record must be finite and non-negative");
  sampling_record_ = r;
}

void AvatarImpl::plan_observation_prior() {
  if (!confidence_.defined()) return;
  const auto options = body_->vertices().options();
  if (confidence_.device() != options.device()) confidence_ = confidence_.to(options.device());
  if (is_training()) return;  // training ignores the record (and may be recording a CUDA graph: no host reads)
  if (propagation_ && propagation_->trust.defined() && propagation_->trust.device() == options.device() &&
      propagation_->trust.scalar_type() == options.dtype().toScalarType())
    return;
  if (propagation_ && !propagation_->any_trusted) return;  // nothing observed: no tensors to move
  propagation_ = std::make_unique<PropagationPlan>(
      plan_propagation(confidence_.squeeze(1), neighbours_, options.dtype().toScalarType()));
}

CanonicalAttributes AvatarImpl::attributes_at(const at::Tensor& device_time) {
  if (!cache_) return compute_attributes(feature_field_->static_features(), device_time);
  TORCH_CHECK(!is_training(),
              "Avatar: the static-feature cache is for inference; call clear_cache() before training (or eval())");
  TORCH_CHECK(cache_->device() == body_->vertices().device(), "Avatar: the cache was made on ", cache_->device(),
              " but the module is on ", body_->vertices().device(), "; call cache_static_features() again");
  CanonicalAttributes a = compute_attributes(cache_->features(), device_time);
  // The fused structure offset reads the projection in half precision, as from the cache.
  if (a.structure_projection.defined() && a.structure_projection.is_cuda())
    a.structure_projection_half = a.structure_projection.to(at::kHalf);
  return a;
}

CanonicalAttributes AvatarImpl::attributes_at(FrameTime time) {
  const auto time_value = [&] { return time ? at::full({}, *time, body_->vertices().options()) : at::Tensor(); };
  if (!cache_) return compute_attributes(feature_field_->static_features(), time_value());
  TORCH_CHECK(!is_training(),
              "Avatar: the static-feature cache is for inference; call clear_cache() before training (or eval())");
  TORCH_CHECK(cache_->device() == body_->vertices().device(), "Avatar: the cache was made on ", cache_->device(),
              " but the module is on ", body_->vertices().device(), "; call cache_static_features() again");
  if (const CanonicalAttributes* kept = cache_->attributes(time)) return *kept;
  cache_->keep(compute_attributes(cache_->features(), time_value()), time);
  // The kept copy: it carries what inference reads (the half-precision projection of the fused structure offset), so
  // a time's first frame equals its later ones and a recorded frame at that time.
  return *cache_->attributes(time);
}

CanonicalGaussians AvatarImpl::canonical_gaussians(const FramePose& frame, const FrameBody& body,
                                                   const CanonicalAttributes& attributes, PoseGradient gradient) const {
  CanonicalGaussians g;
  g.means = body.rest + attributes.mean_offset;
  g.log_scales = attributes.log_scales;
  if (structure_offset_) {
    // Inference from the cache on CUDA: the whole network as one fused kernel (gathered_mlp.h); a gradient
    // (training, or through the pose) takes the network layer by layer, its first layer fused (gathered_first_layer).
    const bool held = gradient == PoseGradient::kSkeleton;
    const bool fused = attributes.structure_projection_half.defined() && (held || !at::GradMode::is_enabled());
    StructureOffsetOutput structure;
    {
      std::optional<at::NoGradGuard> no_gradient;
      if (held) no_gradient.emplace();
      structure = fused ? structure_offset_->forward_inference(attributes.structure_projection_half,
                                                               frame.rotations_6d.detach())
                        : structure_offset_->forward(attributes.structure_projection, frame.rotations_6d);
    }
    g.structure_offset = trusted(structure.mean_offset);
    g.scale_offset = trusted(structure.log_scale_offset.unsqueeze(1)).squeeze(1);
    g.means = g.means + g.structure_offset;
    g.log_scales = g.log_scales + g.scale_offset;
  }
  if (body.point_offsets.defined()) g.means = g.means + body.point_offsets;  // the hand residual
  return g;
}

at::Tensor AvatarImpl::appearance(const FramePose& frame, const CanonicalAttributes& attributes, bool replay,
                                  PoseGradient gradient, AvatarOutput& out) const {
  at::Tensor logits = attributes.colour_logits;
  if (colour_offset_ && (replay || config_.colour_offset_on_new_motions)) {
    std::optional<at::NoGradGuard> no_gradient;
    if (gradient == PoseGradient::kSkeleton) no_gradient.emplace();
    const at::Tensor pose_embedding = body_->weights().matmul(frame.rotations_6d);  // sum_j w_ij r_j
    out.colour_offset =
        trusted(colour_offset_->forward(attributes.colour_projection, pose_embedding, out.posed_normals));
    logits = logits + out.colour_offset;
  }
  out.albedo = at::sigmoid(logits);
  if (!shading_) return out.albedo;
  out.shading = shading_->forward(out.posed_normals);
  return out.albedo * out.shading;
}

void AvatarImpl::cache_static_features() {
  at::NoGradGuard no_grad;
  plan_observation_prior();
  ++cache_generation_;
  cache_ = std::make_unique<InferenceCache>(feature_field_->static_features(), config_.use_hexplane);
  cache_->keep(compute_attributes(cache_->features(), at::Tensor()), std::nullopt);
}

void AvatarImpl::clear_cache() {
  if (cache_) ++cache_generation_;
  cache_.reset();
}

Gaussians to_gaussians(const AvatarOutput& out) {
  Gaussians g;
  g.means = out.means;
  g.covariances = out.covariances;
  g.opacities = out.opacities;
  g.features = out.colours;
  return g;
}

int64_t AvatarImpl::gaussian_count() const { return body_->point_count(); }
int64_t AvatarImpl::expression_count() const { return body_->expression_count(); }
const at::Tensor& AvatarImpl::part_labels() const { return body_->part_labels(); }
const at::Tensor& AvatarImpl::faces() const { return body_->faces(); }
int64_t AvatarImpl::model_vertex_count() const { return body_->coarse_vertex_count(); }
const skin::SkinningWeights& AvatarImpl::skinning_weights() const { return body_->skinning_weights(); }
at::Tensor AvatarImpl::shading_coefficients() const { return shading_ ? shading_->coefficients() : at::Tensor(); }
const at::Tensor& AvatarImpl::hand_mean(body::Side side) const { return body_->hand_mean(side); }
const AvatarConfig& AvatarImpl::config() const { return config_; }

int64_t parameter_count(const AvatarConfig& c, bool has_mano) {
  check_config(c);
  const int64_t width = 3 * c.plane_channels, h = c.hidden_width;
  int64_t count = FeatureFieldImpl::parameter_count(field_options(c));
  count += MlpImpl::parameter_count(CanonicalHeadsImpl::geometry_shape(width, h));
  count += MlpImpl::parameter_count(CanonicalHeadsImpl::colour_shape(width, h));
  if (c.use_structure_offset)
    count += body::kSmplxJointCount * c.joint_embedding_size +
             MlpImpl::parameter_count(StructureOffsetImpl::shape(width, h, c.joint_embedding_size));
  if (c.use_colour_offset) count += MlpImpl::parameter_count(ColourOffsetImpl::shape(width, h));
  if (c.use_shading) count += ShadingImpl::kBasisSize * 3;
  if (c.use_hand_residual && has_mano) count += 2 * MlpImpl::parameter_count(HandResidualImpl::shape());
  return count;
}

}  // namespace sfgs::model
