#include "model/inference_cache.h"

#include <utility>

namespace sfgs::model {

InferenceCache::InferenceCache(StaticFeatures features, bool time_dependent)
    : features_(std::move(features)), time_dependent_(time_dependent) {}

const CanonicalAttributes* InferenceCache::attributes(double time) const {
  if (!attributes_ || (time_dependent_ && time != time_)) return nullptr;
  return &*attributes_;
}

void InferenceCache::keep(const CanonicalAttributes& attributes, double time) {
  CanonicalAttributes kept = attributes;
  for (at::Tensor* t : {&kept.mean_offset, &kept.log_scales, &kept.colour_logits, &kept.structure_projection,
                        &kept.colour_projection})
    if (t->defined()) *t = t->detach();
  attributes_ = std::move(kept);
  time_ = time;
}

}  // namespace sfgs::model
