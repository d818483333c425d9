#pragma once
// What an avatar keeps between frames at inference: the features that depend on neither pose nor time, and the
// canonical attributes the fused feature determines: those without a time (new motions) and those of the last time
// they were computed at (without the hexplane one set holds for every time). Training never uses it: its tensors
// are detached.
#include <optional>

#include <ATen/core/Tensor.h>

#include "model/feature_field.h"
#include "model/frame_time.h"

namespace sfgs::model {

// What the fused feature determines for every point: the canonical attributes and the feature's share of the
// pose-driven networks' first layers (undefined where that network is switched off).
struct CanonicalAttributes {
  at::Tensor mean_offset;           // (N, 3)
  at::Tensor log_scales;            // (N) initial log-scale plus the head's offset
  at::Tensor colour_logits;         // (N, 3)
  at::Tensor structure_projection;  // (N, H), structure offset only
  at::Tensor colour_projection;     // (N, H), colour offset only
  // The inference cache's half-precision copy of structure_projection on CUDA, which the fused structure offset
  // reads (half the bytes of a frame's largest read); undefined elsewhere.
  at::Tensor structure_projection_half;
};

class InferenceCache {
 public:
  // time_dependent: whether the attributes change with time (the hexplane is in use).
  InferenceCache(StaticFeatures features, bool time_dependent);

  const StaticFeatures& features() const { return features_; }
  at::Device device() const { return features_.triplane.device(); }
  // The attributes kept for `time`, if any.
  const CanonicalAttributes* attributes(FrameTime time) const;
  // Keeps `attributes` (detached) as those of `time`.
  void keep(const CanonicalAttributes& attributes, FrameTime time);

 private:
  bool timeless(FrameTime time) const { return !time || !time_dependent_; }

  StaticFeatures features_;
  bool time_dependent_;
  std::optional<CanonicalAttributes> timeless_, timed_;
  double time_ = 0.0;  // of timed_
};

}  // namespace sfgs::model
