#pragma once
// Per-element math of the gathered first layer as a training op (gathered_mlp.h: gathered_first_layer), shared by
// the CPU backend and the CUDA kernels, free of torch.
#include <cstdint>
#include <limits>

#include "common/host_device.h"

namespace sfgs::gathered_mlp {

// out = relu(row_inputs + group_inputs[groups]), row by row; a row whose group is outside [0, group_count) gets NaN
// (the CUDA kernels' answer to an index the host never reads; the CPU op refuses such groups before).
template <typename T> struct FirstLayerArrays {
  const T* row_inputs;    // (rows, width)
  const T* group_inputs;  // (group_count, width)
  const int64_t* groups;  // (rows)
  T* out;                 // (rows, width)
  int64_t rows;
  int64_t width;
  int64_t group_count;
};

// grad_rows = grad_out where the forward's out > 0; the groups' gradient (each group's sum of its rows' grad_rows)
// comes as `partial_rows` partial tables, one a share of the rows, which the op adds up in a fixed order: partial p
// holds group_count x width values, group-major.
template <typename T> struct FirstLayerGradientArrays {
  const T* out;           // (rows, width): the forward's
  const T* grad_out;      // (rows, width)
  const int64_t* groups;  // (rows)
  T* grad_rows;           // (rows, width)
  T* group_partials;      // (partial_rows, group_count * width)
  int64_t rows;
  int64_t width;
  int64_t group_count;
  int64_t partial_rows;
};

SFGS_HD bool valid_group(int64_t group, int64_t group_count) { return group >= 0 && group < group_count; }

// ReLU as at::relu: NaN stays NaN.
template <typename T> SFGS_HD T first_layer_value(T row_input, T group_input) {
  const T pre = row_input + group_input;
  return pre < T(0) ? T(0) : pre;
}

template <typename T> SFGS_HD T invalid_group_value() { return std::numeric_limits<T>::quiet_NaN(); }

// ReLU's gradient from its output, as LibTorch's threshold backward: nothing passes where out <= 0, nor where out is
// NaN (a row of an invalid group).
template <typename T> SFGS_HD T first_layer_gradient(T out, T grad_out) { return out > T(0) ? grad_out : T(0); }

}  // namespace sfgs::gathered_mlp
