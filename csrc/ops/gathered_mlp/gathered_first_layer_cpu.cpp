// CPU backend of the gathered first layer: gathered_first_layer_math.h's element steps over parallel ranges of rows.
// The backward sums the groups' gradient into one partial table per task of kRowsPerPartial rows, in row order, so
// the result does not depend on the threads.
#include <algorithm>

#include <ATen/Parallel.h>

#include "ops/gathered_mlp/backend.h"

namespace sfgs::gathered_mlp::cpu {
namespace {

constexpr int64_t kElementsPerTask = 16384;  // at::parallel_for's grain: a task's share is worth a thread
// Rows a partial table sums: enough that the tables (group_count x width each) stay few next to the rows.
constexpr int64_t kRowsPerPartial = 4096;

template <typename T> void forward_rows(const FirstLayerArrays<T>& a) {
  at::parallel_for(0, a.rows, std::max<int64_t>(1, kElementsPerTask / a.width), [&](int64_t begin, int64_t end) {
    for (int64_t row = begin; row < end; ++row) {
      const int64_t group = a.groups[row];
      const T* row_inputs = a.row_inputs + row * a.width;
      const T* group_inputs = valid_group(group, a.group_count) ? a.group_inputs + group * a.width : nullptr;
      T* out = a.out + row * a.width;
      for (int64_t c = 0; c < a.width; ++c)
        out[c] = group_inputs ? first_layer_value(row_inputs[c], group_inputs[c]) : invalid_group_value<T>();
    }
  });
}

template <typename T> void backward_rows(const FirstLayerGradientArrays<T>& a) {
  const int64_t table = a.group_count * a.width;
  at::parallel_for(0, a.partial_rows, 1, [&](int64_t begin, int64_t end) {
    for (int64_t partial = begin; partial < end; ++partial) {
      T* sums = a.group_partials + partial * table;
      std::fill(sums, sums + table, T(0));
      const int64_t last = std::min(a.rows, (partial + 1) * kRowsPerPartial);
      for (int64_t row = partial * kRowsPerPartial; row < last; ++row) {
        const int64_t group = a.groups[row];
        T* group_sums = valid_group(group, a.group_count) ? sums + group * a.width : nullptr;
        for (int64_t c = 0; c < a.width; ++c) {
          const int64_t i = row * a.width + c;
          const T grad = first_layer_gradient(a.out[i], a.grad_out[i]);
          a.grad_rows[i] = grad;
          if (group_sums) group_sums[c] += grad;
        }
      }
    }
  });
}

}  // namespace

int64_t first_layer_partial_rows(int64_t rows) {
  return std::max<int64_t>(1, (rows + kRowsPerPartial - 1) / kRowsPerPartial);
}
void first_layer_forward(const FirstLayerArrays<float>& a) { forward_rows(a); }
void first_layer_forward(const FirstLayerArrays<double>& a) { forward_rows(a); }
void first_layer_backward(const FirstLayerGradientArrays<float>& a) { backward_rows(a); }
void first_layer_backward(const FirstLayerGradientArrays<double>& a) { backward_rows(a); }

}  // namespace sfgs::gathered_mlp::cpu
