#pragma once
// SFGS's coherent mesh representation: every Gaussian reads a triplane feature f_tri (static) and a hexplane
// feature f_hex (space-time); f_hex is mapped to the triplane's width by a linear layer, and a learned per-channel
// gate alpha = sigmoid(MLP([f_tri; f_hex'])) fuses them: f = (1 - alpha) f_tri + alpha f_hex'. Face points read
// dedicated (finer) planes of their own, normalised to the face's bounding box.
//
// The hexplane's XY, XZ and YZ planes do not depend on time, and the linear map is a sum over its input planes,
// so the spatial half (and the gate's triplane half) is computed once per point set: StaticFeatures, cacheable.
// The gate's mix and the merge of body and face rows are single fused passes (ops/feature_fusion/feature_fusion.h).
#include <cstdint>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "ops/feature_fusion/feature_fusion.h"
#include "model/mlp.h"
#include "model/planes.h"

namespace sfgs::model {

struct FeatureFieldOptions {
  int64_t channels = 32;
  int64_t resolution = 128;
  int64_t time_resolution = 32;
  int64_t face_resolution = 256;
  bool use_hexplane = true;
  bool use_face_planes = true;
};

// What a point set's features need that does not depend on time.
struct StaticFeatures {
  at::Tensor triplane;        // (N, 3 C)
  at::Tensor hexplane_space;  // (N, 3 C): the spatial planes' share of f_hex' (bias included); hexplane only
  at::Tensor gate_triplane;   // (N, 3 C): the triplane's share of the gate's first layer; hexplane only
};

class FeatureFieldImpl : public torch::nn::Module {
 public:
  // coordinates (N, 3): every point, normalised to [-1, 1] by the body's bounding box; face_points (K) int64:
  // the points that read the face planes; face_coordinates (K, 3): theirs, normalised by the face's box.
  FeatureFieldImpl(const FeatureFieldOptions& options, const at::Tensor& coordinates, const at::Tensor& face_points,
                   const at::Tensor& face_coordinates);

  int64_t width() const { return 3 * options_.channels; }  // of the fused feature
  static int64_t parameter_count(const FeatureFieldOptions& options);
  StaticFeatures static_features() const;
  // The fused feature (N, 3 C) at normalised time t in [-1, 1] (a 0-dim tensor on the field's device, checked by
  // the caller); without the hexplane, the triplane feature. Without a time (undefined) the time planes' share of
  // f_hex' is left out (a residual that training also leaves out at times, AvatarConfig::time_dropout), so f_hex' is
  // its spatial half.
  at::Tensor fuse(const StaticFeatures& features, const at::Tensor& time) const;

 private:
  static MlpShape hexplane_to_triplane_shape(int64_t channels);
  static MlpShape gate_shape(int64_t channels);
  // Rows sampled from the body planes (non-face points) and from the face planes, merged into point order.
  at::Tensor merge(const at::Tensor& body_rows, const at::Tensor& face_rows) const;
  // merge_order_ with its inverse (feature_fusion::MergeOrder), on merge_order_'s device: made at the first merge
  // there (the inverse is no buffer, so checkpoints keep their layout).
  const feature_fusion::MergeOrder& merge_rows_order() const;

  FeatureFieldOptions options_;
  bool split_face_ = false;  // face planes in use and a face region present
  at::Tensor coordinates_;   // (N, 3), or (N - K, 3) of the non-face points when split_face_
  at::Tensor face_coordinates_;
  at::Tensor merge_order_;  // (N): row of each point in cat(body rows, face rows)
  mutable feature_fusion::MergeOrder merge_rows_order_;
  mutable const void* merge_rows_order_of_ = nullptr;  // merge_order_'s data when merge_rows_order_ was made
  Triplane triplane_{nullptr}, face_triplane_{nullptr}, hexplane_space_{nullptr}, face_hexplane_space_{nullptr};
  TimePlanes hexplane_time_{nullptr}, face_hexplane_time_{nullptr};
  Mlp hexplane_to_triplane_{nullptr};  // groups: spatial planes (with the bias), time planes; no hidden layer
  Mlp gate_{nullptr};                  // groups: f_tri, f_hex'
};
TORCH_MODULE(FeatureField);

}  // namespace sfgs::model
