#include "model/feature_field.h"

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/tensor_checks.h"

namespace sfgs::model {

// One linear layer from the hexplane's six planes (spatial three with the bias, then the time three) to 3 C.
MlpShape FeatureFieldImpl::hexplane_to_triplane_shape(int64_t channels) {
  return MlpShape{{3 * channels, 3 * channels}, {}, 3 * channels};
}

// The authors' gate: [f_tri; f_hex'] -> 3 C -> ReLU -> 3 C (then a sigmoid).
MlpShape FeatureFieldImpl::gate_shape(int64_t channels) {
  return MlpShape{{3 * channels, 3 * channels}, {3 * channels}, 3 * channels};
}

int64_t FeatureFieldImpl::parameter_count(const FeatureFieldOptions& o) {
  const int64_t c = o.channels, r = o.resolution, t = o.time_resolution, rf = o.face_resolution;
  int64_t count = 3 * c * r * r;                    // triplane
  if (o.use_face_planes) count += 3 * c * rf * rf;  // face triplane
  if (o.use_hexplane) {
    count += 3 * c * r * r + 3 * c * t * r;  // hexplane: spatial and time planes
    if (o.use_face_planes) count += 3 * c * rf * rf + 3 * c * t * rf;
    count += MlpImpl::parameter_count(hexplane_to_triplane_shape(c)) + MlpImpl::parameter_count(gate_shape(c));
  }
  return count;
}

FeatureFieldImpl::FeatureFieldImpl(const FeatureFieldOptions& options, const at::Tensor& coordinates,
                                   const at::Tensor& face_points, const at::Tensor& face_coordinates)
    : options_(options) {
  TORCH_CHECK(coordinates.defined() && coordinates.dim() == 2 && coordinates.size(1) == 3 &&
                  at::isFloatingType(coordinates.scalar_type()),
              "FeatureField: coordinates must be a floating (N, 3) tensor, got ", describe(coordinates));
  const int64_t n = coordinates.size(0);
  TORCH_CHECK(face_points.defined() && face_points.dim() == 1 && face_points.scalar_type() == at::kLong,
              "FeatureField: face_points must be an int64 (K) tensor, got ", describe(face_points));
  const int64_t k = face_points.size(0);
  TORCH_CHECK(face_coordinates.defined() && face_coordinates.sizes() == at::IntArrayRef({k, 3}),
              "FeatureField: face_coordinates must have shape (", k, ", 3), got ", describe(face_coordinates));
  TORCH_CHECK(!options_.use_face_planes || k > 0,
              "FeatureField: the face planes need face points, but the body has no face region (switch "
              "use_face_planes off, or give the face vertex ids)");
  const auto float_cpu = at::TensorOptions().dtype(at::kFloat);
  split_face_ = options_.use_face_planes;
  if (split_face_) {
    at::Tensor is_face = at::zeros({n}, at::kBool);
    is_face.index_fill_(0, face_points, true);
    const at::Tensor body_points = is_face.logical_not().nonzero().flatten();
    at::Tensor merge_order = at::empty({n}, at::kLong);
    merge_order.index_copy_(0, at::cat({body_points, face_points}), at::arange(n, at::kLong));
    coordinates_ = register_buffer("coordinates", coordinates.index_select(0, body_points).to(float_cpu));
    face_coordinates_ = register_buffer("face_coordinates", face_coordinates.to(float_cpu));
    merge_order_ = register_buffer("merge_order", merge_order);
  } else {
    coordinates_ = register_buffer("coordinates", coordinates.to(float_cpu));
  }

  const int64_t c = options_.channels;
  triplane_ = register_module("triplane", Triplane(c, options_.resolution));
  if (split_face_) face_triplane_ = register_module("face_triplane", Triplane(c, options_.face_resolution));
  if (options_.use_hexplane) {
    hexplane_space_ = register_module("hexplane_space", Triplane(c, options_.resolution));
    hexplane_time_ = register_module("hexplane_time", TimePlanes(c, options_.resolution, options_.time_resolution));
    if (split_face_) {
      face_hexplane_space_ = register_module("face_hexplane_space", Triplane(c, options_.face_resolution));
      face_hexplane_time_ =
          register_module("face_hexplane_time", TimePlanes(c, options_.face_resolution, options_.time_resolution));
    }
    hexplane_to_triplane_ = register_module("hexplane_to_triplane", Mlp(hexplane_to_triplane_shape(c)));
    gate_ = register_module("gate", Mlp(gate_shape(c)));
  }
}

const feature_fusion::MergeOrder& FeatureFieldImpl::merge_rows_order() const {
  if (merge_rows_order_of_ != merge_order_.data_ptr()) {
    at::Tensor inverse = at::empty_like(merge_order_);
    inverse.index_copy_(0, merge_order_, at::arange(merge_order_.size(0), merge_order_.options()));
    merge_rows_order_ = {merge_order_, inverse, coordinates_.size(0)};
    merge_rows_order_of_ = merge_order_.data_ptr();
  }
  return merge_rows_order_;
}

at::Tensor FeatureFieldImpl::merge(const at::Tensor& body_rows, const at::Tensor& face_rows) const {
  return feature_fusion::merge_rows(body_rows, face_rows, merge_rows_order());
}

StaticFeatures FeatureFieldImpl::static_features() const {
  StaticFeatures features;
  features.triplane = split_face_ ? merge(triplane_->sample(coordinates_), face_triplane_->sample(face_coordinates_))
                                  : triplane_->sample(coordinates_);
  if (options_.use_hexplane) {
    const at::Tensor space =
        split_face_ ? merge(hexplane_space_->sample(coordinates_), face_hexplane_space_->sample(face_coordinates_))
                    : hexplane_space_->sample(coordinates_);
    features.hexplane_space = hexplane_to_triplane_->project(0, space);
    features.gate_triplane = gate_->project(0, features.triplane);
  }
  return features;
}

at::Tensor FeatureFieldImpl::fuse(const StaticFeatures& features, const at::Tensor& time) const {
  if (!options_.use_hexplane) return features.triplane;
  at::Tensor aligned = features.hexplane_space;
  if (time.defined()) {
    const at::Tensor time_features = split_face_ ? merge(hexplane_time_->sample(coordinates_, time),
                                                         face_hexplane_time_->sample(face_coordinates_, time))
                                                 : hexplane_time_->sample(coordinates_, time);
    aligned = hexplane_to_triplane_->project_add(1, time_features, aligned);
  }
  const at::Tensor gate_logits = gate_->finish(gate_->project_add(1, aligned, features.gate_triplane));
  return feature_fusion::gated_mix(gate_logits, features.triplane, aligned);  // (1 - alpha) f_tri + alpha f_hex
}

}  // namespace sfgs::model
