#include "model/inference_cache.h"

#include <utility>

namespace sfgs::model {

InferenceCache::InferenceCache(StaticFeatures features, bool time_dependent)
    : features_(std::move(features)), time_dependent_(time_dependent) {}

const CanonicalAttributes* InferenceCache::attributes(FrameTime time) const {
  if (timeless(time)) return timeless_ ? &*timeless_ : nullptr;
  return timed_ && *time == time_ ? &*timed_ : nullptr;
}

void InferenceCache::keep(const CanonicalAttributes& attributes, FrameTime time) {
  CanonicalAttributes kept = attributes;
  for (at::Tensor* t :
       {&kept.mean_offset, &kept.log_scales, &kept.colour_logits, &kept.structure_projection, &kept.colour_projection})
    if (t->defined()) *t = t->detach();
  if (kept.structure_projection.defined() && kept.structure_projection.is_cuda())
    kept.structure_projection_half = kept.structure_projection.to(at::kHalf);
  if (timeless(time)) {
    timeless_ = std::move(kept);
  } else {
    timed_ = std::move(kept);
    time_ = *time;
  }
}

}  // namespace sfgs::model
