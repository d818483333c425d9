// CPU backend of the feature-fusion ops: feature_fusion_math.h's element and row steps over parallel ranges.
#include <algorithm>
#include <limits>

#include <ATen/Parallel.h>

#include "ops/feature_fusion/backend.h"

namespace sfgs::feature_fusion::cpu {
namespace {

constexpr int64_t kElementsPerTask = 16384;  // at::parallel_for's grain: a task's share is worth a thread

template <typename T> void mix(const GatedMixArrays<T>& a) {
  at::parallel_for(0, a.count, kElementsPerTask, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) a.out[i] = gated_mix_value(a.logits[i], a.a[i], a.b[i]);
  });
}

template <typename T> void mix_backward(const GatedMixGradientArrays<T>& a) {
  at::parallel_for(0, a.count, kElementsPerTask, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const GatedMixGradient<T> g = gated_mix_gradient(a.logits[i], a.a[i], a.b[i], a.grad_out[i]);
      a.grad_logits[i] = g.logit;
      a.grad_a[i] = g.a;
      a.grad_b[i] = g.b;
    }
  });
}

template <typename T> void gather(const RowGatherArrays<T>& r) {
  at::parallel_for(0, r.rows, std::max<int64_t>(1, kElementsPerTask / std::max<int64_t>(1, r.columns)),
                   [&](int64_t begin, int64_t end) {
                     for (int64_t row = begin; row < end; ++row) {
                       const SourceRow<T> from = gather_source_row(r, row);
                       T* to = gather_destination_row(r, row);
                       for (int64_t c = 0; c < r.columns; ++c)
                         to[c] = from.values != nullptr ? from.values[c * from.column_stride]
                                                        : std::numeric_limits<T>::quiet_NaN();
                     }
                   });
}

}  // namespace

void gated_mix(const GatedMixArrays<float>& a) { mix(a); }
void gated_mix(const GatedMixArrays<double>& a) { mix(a); }
void gated_mix_backward(const GatedMixGradientArrays<float>& a) { mix_backward(a); }
void gated_mix_backward(const GatedMixGradientArrays<double>& a) { mix_backward(a); }
void gather_rows(const RowGatherArrays<float>& a) { gather(a); }
void gather_rows(const RowGatherArrays<double>& a) { gather(a); }

}  // namespace sfgs::feature_fusion::cpu
