#pragma once
// The feature field's fusion steps (model/feature_field.h) as single passes: the gate's mix of the triplane and
// hexplane features, and the merge of the body planes' rows with the face planes' rows into point order. LibTorch
// composes the mix of six element-wise passes over the (N, 3C) features forward and seven backward, and the merge of
// a concatenation and an index_select forward and a zero fill and an atomic index_add backward; at 216k points those
// were about 2 ms of a training step (docs/performance.md). Each op here is one kernel forward and one backward (a
// CPU backend and a CUDA kernel of one math header, feature_fusion_math.h, one autograd node each); the *_reference
// functions are the LibTorch compositions they are tested against.
#include <ATen/core/Tensor.h>

namespace sfgs::feature_fusion {

// (1 - alpha) a + alpha b with alpha = sigmoid(logits) (exactly a or b where the gate saturates): all three of one
// shape, floating dtype (float or double) and device. Differentiable in all three.
at::Tensor gated_mix(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b);
at::Tensor gated_mix_reference(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b);

// Where each point's row comes from when the rows of two point subsets are merged into point order.
struct MergeOrder {
  at::Tensor source;       // (N) int64: point i's row in cat(first, second)
  at::Tensor inverse;      // (N) int64: row j of cat(first, second) is point inverse[j]'s
  int64_t first_rows = 0;  // rows of the first subset

  // `first_points` (N1) and `second_points` (N2) int64: the points of each subset, in their rows' order; together
  // every point of 0..N-1 once (N = N1 + N2), else an error naming the point.
  static MergeOrder of(const at::Tensor& first_points, const at::Tensor& second_points);
  MergeOrder to(at::Device device) const;
};

// cat(first, second).index_select(0, order.source): first (N1, C) and second (N2, C) of one floating dtype and
// device (order's there too). Differentiable in both (the backward is a gather as well: no atomic adds).
at::Tensor merge_rows(const at::Tensor& first, const at::Tensor& second, const MergeOrder& order);
at::Tensor merge_rows_reference(const at::Tensor& first, const at::Tensor& second, const MergeOrder& order);

}  // namespace sfgs::feature_fusion
