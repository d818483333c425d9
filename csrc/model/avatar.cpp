#include "model/avatar.h"

#include <cmath>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "common/constants.h"
#include "model/skinning.h"

namespace sfgs::model {
namespace {

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
              "Avatar: AvatarPose::", name, " must be a floating (", joints, ", 3) or (", 3 * joints, ") tensor, got ",
              body::describe(pose));
  return pose.reshape({joints, 3}).to(options);
}

// Refuses NaN and Inf anywhere in the pose, naming the field and the first bad value. Poses on the CPU are checked
// where they lie; device ones with one combined reduction (a single synchronisation).
void check_pose_finite(const AvatarPose& pose) {
  const std::pair<const char*, const at::Tensor*> fields[] = {
      {"global_orient", &pose.global_orient},   {"body_pose", &pose.body_pose},
      {"jaw_pose", &pose.jaw_pose},             {"left_eye_pose", &pose.left_eye_pose},
      {"right_eye_pose", &pose.right_eye_pose}, {"left_hand_pose", &pose.left_hand_pose},
      {"right_hand_pose", &pose.right_hand_pose}, {"expression", &pose.expression},
      {"transl", &pose.transl}};
  std::vector<at::Tensor> on_device;
  for (const auto& [name, t] : fields)
    if (t->defined() && !t->is_cpu() && at::isFloatingType(t->scalar_type())) on_device.push_back(t->detach().flatten());
  if (!on_device.empty() && at::cat(on_device).isfinite().all().item<bool>()) on_device.clear();
  for (const auto& [name, t] : fields) {
    if (!t->defined() || !at::isFloatingType(t->scalar_type()) || (!t->is_cpu() && on_device.empty())) continue;
    const at::Tensor flat = t->detach().flatten().cpu();
    const at::Tensor bad = (~flat.isfinite()).nonzero();
    TORCH_CHECK(bad.numel() == 0, "Avatar: AvatarPose::", name, " must be finite, got ", flat[bad[0][0]].item<double>(),
                " at index ", bad[0][0].item<int64_t>(), " (", bad.size(0), " of ", flat.numel(), " values are not finite)");
  }
}

at::Tensor vector_input(const at::Tensor& t, const char* name, const at::TensorOptions& options) {
  TORCH_CHECK(at::isFloatingType(t.scalar_type()) && (t.dim() == 1 || (t.dim() == 2 && t.size(0) == 1)),
              "Avatar: AvatarPose::", name, " must be a floating (n) or (1, n) tensor, got ", body::describe(t));
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
  if (config_.use_color_offset)
    colour_offset_ = register_module("colour_offset", ColourOffset(width, config_.hidden_width));
  if (config_.use_hand_residual && b.has_mano) {
    body::ManoModelData left = b.mano_left;
    body::repair_left_mano_shapedirs(left, b.mano_right);
    hand_residual_ = register_module(
        "hand_residual", HandResidual(b.smplx, shaped.vertices, shaped.joints, left, b.mano_right, b.hand_vertex_ids));
  }
  opacities_ = register_buffer("opacities", at::ones({n}));
}

AvatarImpl::CanonicalAttributes AvatarImpl::canonical_attributes(const StaticFeatures& features, double time) const {
  const at::Tensor fused = feature_field_->fuse(features, time);
  const CanonicalHeadOutput heads = heads_->forward(fused);
  CanonicalAttributes a;
  a.mean_offset = heads.mean_offset;
  a.log_scales = body_->initial_log_scales() + heads.log_scale_offset;
  a.colour_logits = heads.colour_logits;
  if (structure_offset_) a.structure_projection = structure_offset_->project_features(fused);
  if (colour_offset_) a.colour_projection = colour_offset_->project_features(fused);
  return a;
}

AvatarOutput AvatarImpl::forward(const AvatarPose& pose) {
  TORCH_CHECK(std::isfinite(pose.time) && pose.time >= -1.0 && pose.time <= 1.0,
              "Avatar: AvatarPose::time must be normalised to [-1, 1] (once per sequence), got ", pose.time);
  check_pose_finite(pose);
  const auto options = body_->vertices().options();
  const int64_t n = body_->point_count();

  // Canonical attributes: from the cache where it holds them, else computed (and kept when caching).
  if (cache_) {
    TORCH_CHECK(!is_training(),
                "Avatar: the static-feature cache is for inference; call clear_cache() before training (or eval())");
    TORCH_CHECK(cache_->features.triplane.device() == options.device(), "Avatar: the cache was made on ",
                cache_->features.triplane.device(), " but the module is on ", options.device(),
                "; call cache_static_features() again");
  }
  const StaticFeatures features = cache_ ? cache_->features : feature_field_->static_features();
  CanonicalAttributes attributes;
  if (cache_ && cache_->attributes && (!config_.use_hexplane || cache_->time == pose.time)) {
    attributes = *cache_->attributes;
  } else {
    attributes = canonical_attributes(features, pose.time);
    if (cache_) {
      CanonicalAttributes kept = attributes;
      for (at::Tensor* t : {&kept.mean_offset, &kept.log_scales, &kept.colour_logits, &kept.structure_projection,
                            &kept.colour_projection})
        if (t->defined()) *t = t->detach();
      cache_->attributes = kept;
      cache_->time = pose.time;
    }
  }

  // The frame's skeleton and rest mesh.
  const at::Tensor left_hand = joint_pose(pose.left_hand_pose, body::kHandJointCount, "left_hand_pose", options);
  const at::Tensor right_hand = joint_pose(pose.right_hand_pose, body::kHandJointCount, "right_hand_pose", options);
  const bool add_mean = !config_.flat_hand_mean;
  const at::Tensor axis_angle = at::cat({joint_pose(pose.global_orient, 1, "global_orient", options),
                                         joint_pose(pose.body_pose, body::kSmplxBodyJointCount, "body_pose", options),
                                         joint_pose(pose.jaw_pose, 1, "jaw_pose", options),
                                         joint_pose(pose.left_eye_pose, 1, "left_eye_pose", options),
                                         joint_pose(pose.right_eye_pose, 1, "right_eye_pose", options),
                                         add_mean ? left_hand + body_->hand_mean(body::Side::kLeft) : left_hand,
                                         add_mean ? right_hand + body_->hand_mean(body::Side::kRight) : right_hand});
  const at::Tensor rotations = body::axis_angle_to_matrix(axis_angle);
  at::Tensor expression;
  if (pose.expression.defined() && body_->expression_count() > 0) {
    const at::Tensor given = vector_input(pose.expression, "expression", options);
    const int64_t used = std::min(given.size(0), body_->expression_count());
    expression = at::constant_pad_nd(given.narrow(0, 0, used), {0, body_->expression_count() - used});
  }
  at::Tensor translation = at::zeros({3}, options);
  if (pose.transl.defined()) {
    translation = vector_input(pose.transl, "transl", options);
    TORCH_CHECK(translation.size(0) == 3, "Avatar: AvatarPose::transl must have 3 values, got ", translation.size(0));
  }
  const body::PosedSkeleton skeleton = body_->pose(rotations, body_->rest_joints(expression), translation);
  const at::Tensor blended = blend_transforms(body_->weights(), skeleton.skinning_transforms);
  const at::Tensor displacement = body_->coarse_displacement(expression, rotations);
  const at::Tensor rest =
      displacement.defined() ? body_->vertices() + body_->subdivide(displacement) : body_->vertices();

  // Canonical Gaussians: the rest mesh plus every offset.
  AvatarOutput out;
  out.mean_offset = attributes.mean_offset;
  at::Tensor canonical = rest + attributes.mean_offset;
  at::Tensor log_scales = attributes.log_scales;
  const at::Tensor rotations_6d = body::matrix_to_rotation_6d(rotations);
  if (structure_offset_) {
    const StructureOffsetOutput structure = structure_offset_->forward(attributes.structure_projection, rotations_6d);
    out.structure_offset = structure.mean_offset;
    out.scale_offset = structure.log_scale_offset;
    canonical = canonical + structure.mean_offset;
    log_scales = log_scales + structure.log_scale_offset;
  } else {
    out.structure_offset = at::zeros({n, 3}, options);
    out.scale_offset = at::zeros({n}, options);
  }
  if (hand_residual_) {
    const auto hand_pose = [&](const at::Tensor& given, body::Side side) {
      return given.defined() ? axis_angle.narrow(0, body::smplx_hand_joint(side, 1), body::kHandJointCount)
                             : at::Tensor();
    };
    const at::Tensor coarse = hand_residual_->forward(hand_pose(pose.left_hand_pose, body::Side::kLeft),
                                                      hand_pose(pose.right_hand_pose, body::Side::kRight));
    if (coarse.defined()) {
      out.hand_residual = body_->subdivide(coarse);
      canonical = canonical + out.hand_residual;
    }
  }
  if (!out.hand_residual.defined()) out.hand_residual = at::zeros({n, 3}, options);
  out.canonical_means = canonical;
  out.log_scales = log_scales;

  // Skinning into the world.
  out.means = transform_points(blended, canonical);
  out.covariances = isotropic_covariances(blended, log_scales);
  out.posed_vertices = transform_points(blended, rest);
  out.opacities = opacities_;

  at::Tensor colour_logits = attributes.colour_logits;
  if (colour_offset_) {
    at::Tensor normals;
    {
      // The body-model surface's orientation: smooth, free of the learned offsets' noise, and no gradient.
      at::NoGradGuard no_grad;
      normals = vertex_normals(out.posed_vertices.detach(), body_->faces());
    }
    const at::Tensor pose_embedding = body_->weights().matmul(rotations_6d);  // sum_j w_ij r_j
    out.colour_offset = colour_offset_->forward(attributes.colour_projection, pose_embedding, normals);
    colour_logits = colour_logits + out.colour_offset;
  } else {
    out.colour_offset = at::zeros({n, 3}, options);
  }
  out.colours = at::sigmoid(colour_logits);
  return out;
}

void AvatarImpl::cache_static_features() {
  at::NoGradGuard no_grad;
  Cache cache;
  cache.features = feature_field_->static_features();
  if (!config_.use_hexplane) cache.attributes = canonical_attributes(cache.features, 0.0);
  cache_ = std::move(cache);
}

void AvatarImpl::clear_cache() { cache_.reset(); }

Gaussians to_gaussians(const AvatarOutput& out) {
  Gaussians g;
  g.means = out.means;
  g.covariances = out.covariances;
  g.opacities = out.opacities;
  g.features = out.colours;
  return g;
}

int64_t AvatarImpl::gaussian_count() const { return body_->point_count(); }
const at::Tensor& AvatarImpl::part_labels() const { return body_->part_labels(); }
const at::Tensor& AvatarImpl::faces() const { return body_->faces(); }
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
  if (c.use_color_offset) count += MlpImpl::parameter_count(ColourOffsetImpl::shape(width, h));
  if (c.use_hand_residual && has_mano) count += 2 * MlpImpl::parameter_count(HandResidualImpl::shape());
  return count;
}

}  // namespace sfgs::model
