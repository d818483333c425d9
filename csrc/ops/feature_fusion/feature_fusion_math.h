#pragma once
// Per-element math of the feature field's fusion ops (feature_fusion.h), shared by the CPU backend and the CUDA
// kernels, free of torch.
#include <cmath>
#include <cstdint>

#include "common/host_device.h"

namespace sfgs::feature_fusion {

// out = (1 - sigmoid(logits)) a + sigmoid(logits) b over `count` elements.
template <typename T> struct GatedMixArrays {
  const T* logits;
  const T* a;
  const T* b;
  T* out;
  int64_t count;
};

template <typename T> struct GatedMixGradientArrays {
  const T* logits;
  const T* a;
  const T* b;
  const T* grad_out;
  T* grad_logits;
  T* grad_a;
  T* grad_b;
  int64_t count;
};

// Rows of `columns` values moved from two sources to two destinations: destination row r (r < out_first_rows: row r
// of out_first, else row r - out_first_rows of out_second) is source row source[r] (s < first_rows: row s of first,
// else row s - first_rows of second). The merge's forward reads two sources into one destination (out_second
// null), its backward one source into two destinations (second null). The sources may be strided (the planes' rows
// arrive as a transposed view); the destinations are contiguous rows.
template <typename T> struct RowGatherArrays {
  const T* first;
  int64_t first_row_stride, first_column_stride;
  const T* second;
  int64_t second_row_stride, second_column_stride;
  int64_t first_rows;
  const int64_t* source;
  T* out_first;
  T* out_second;
  int64_t out_first_rows;
  int64_t rows;  // destination rows in all
  int64_t columns;
  int64_t source_rows;  // rows of first and second together: a source index outside [0, source_rows) gives NaNs
};

// sigmoid without overflow: exp of a non-positive number only.
template <typename T> SFGS_HD T stable_sigmoid(T x) {
  if (x >= T(0)) return T(1) / (T(1) + exp(-x));
  const T e = exp(x);
  return e / (T(1) + e);
}

// (1 - s) a + s b rather than a + s (b - a): exactly a or b where the gate saturates.
template <typename T> SFGS_HD T gated_mix_value(T logit, T a, T b) {
  const T s = stable_sigmoid(logit);
  return (T(1) - s) * a + s * b;
}

template <typename T> struct GatedMixGradient { T logit, a, b; };

// d out / d logit = s (1 - s) (b - a), d out / d a = 1 - s, d out / d b = s, times the output's gradient g.
template <typename T> SFGS_HD GatedMixGradient<T> gated_mix_gradient(T logit, T a, T b, T g) {
  const T s = stable_sigmoid(logit);
  return {g * s * (T(1) - s) * (b - a), g * (T(1) - s), g * s};
}

// Source row `row`'s first value and its stride along the columns.
template <typename T> struct SourceRow {
  const T* values;
  int64_t column_stride;
};

// Null values for a source index out of range: the destination row is NaN (the op's kernels are reachable from
// torch.ops without MergeOrder's checks, and checking the indices on the host would cost a device read).
template <typename T> SFGS_HD SourceRow<T> gather_source_row(const RowGatherArrays<T>& r, int64_t row) {
  const int64_t s = r.source[row];
  if (s < 0 || s >= r.source_rows) return {nullptr, 0};
  if (s < r.first_rows) return {r.first + s * r.first_row_stride, r.first_column_stride};
  return {r.second + (s - r.first_rows) * r.second_row_stride, r.second_column_stride};
}

template <typename T> SFGS_HD T* gather_destination_row(const RowGatherArrays<T>& r, int64_t row) {
  return row < r.out_first_rows ? r.out_first + row * r.columns : r.out_second + (row - r.out_first_rows) * r.columns;
}

}  // namespace sfgs::feature_fusion
