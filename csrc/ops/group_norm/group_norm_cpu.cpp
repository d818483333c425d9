// CPU backend of the fused GroupNorm + ReLU op: group_norm_math.h's row steps in a parallel loop; the backward's
// column sums go to one partial row per task of kRowsPerTask rows, so the result does not depend on the threads.
#include <algorithm>

#include <ATen/Parallel.h>

#include "ops/group_norm/backend.h"

namespace sfgs::group_norm::cpu {
namespace {

constexpr int64_t kRowsPerTask = 1024;

template <typename T> void forward_rows(const GroupNormArrays<T>& a) {
  at::parallel_for(0, a.rows, kRowsPerTask, [&](int64_t begin, int64_t end) {
    for (int64_t row = begin; row < end; ++row) forward_row(a, row);
  });
}

template <typename T> void backward_rows(const GroupNormGradientArrays<T>& a) {
  at::parallel_for(0, a.partial_rows, 1, [&](int64_t begin, int64_t end) {
    for (int64_t task = begin; task < end; ++task) {
      T* columns = a.column_partials + task * 3 * a.channels;
      std::fill(columns, columns + 3 * a.channels, T(0));
      const int64_t last = std::min(a.rows, (task + 1) * kRowsPerTask);
      for (int64_t row = task * kRowsPerTask; row < last; ++row) backward_row(a, row, columns);
    }
  });
}

}  // namespace

int64_t partial_rows(int64_t rows) { return std::max<int64_t>(1, (rows + kRowsPerTask - 1) / kRowsPerTask); }
void forward(const GroupNormArrays<float>& a) { forward_rows(a); }
void forward(const GroupNormArrays<double>& a) { forward_rows(a); }
void backward(const GroupNormGradientArrays<float>& a) { backward_rows(a); }
void backward(const GroupNormGradientArrays<double>& a) { backward_rows(a); }

}  // namespace sfgs::group_norm::cpu
