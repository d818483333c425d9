#pragma once
// The fused GroupNorm + affine + ReLU of the avatar's MLPs, written once for the CPU backend (float and double) and
// the CUDA kernels: the arrays both loop over and the per-element steps they take. For a row h = pre + bias of C
// channels in G groups of S = C / G,
//   xhat = (h - mean_g) * rstd_g,  rstd_g = 1 / sqrt(var_g + epsilon)  (biased variance, torch.nn.GroupNorm's)
//   y = gamma * xhat + beta,  out = max(y, 0).
// The backward of a row, from the output's gradient go: gy = go where y > 0 (else 0), gxhat = gamma * gy, and
//   grad_h = rstd_g * (gxhat - mean_g(gxhat) - xhat * mean_g(gxhat * xhat)),
// which is also the gradient of pre and, summed over the rows, of the bias; gamma's is sum(gy * xhat), beta's
// sum(gy). No torch in here.
#include <cmath>
#include <cstdint>

#include "common/host_device.h"

namespace sfgs::group_norm {

// The forward's inputs and outputs; bias may be null (none). Rows are contiguous (rows, channels).
template <typename T> struct GroupNormArrays {
  const T* pre;    // (rows, channels)
  const T* bias;   // (channels) or null
  const T* gamma;  // (channels)
  const T* beta;   // (channels)
  T* out;          // (rows, channels)
  T* mean;         // (rows, groups): each group's mean of h, for the backward
  T* rstd;         // (rows, groups): each group's 1 / sqrt(var + epsilon)
  int64_t rows;
  int channels, groups;
  T epsilon;
};

// The backward's: column_partials holds, per partial row p, the sums over the rows the backend gave p of gamma's,
// beta's and the bias's gradients (3 x channels, in that order); the op sums the partial rows.
template <typename T> struct GroupNormGradientArrays {
  const T* pre;
  const T* bias;  // or null
  const T* gamma;
  const T* beta;
  const T* mean;
  const T* rstd;
  const T* grad_out;   // (rows, channels)
  T* grad_pre;         // (rows, channels)
  T* column_partials;  // (partial_rows, 3 x channels)
  int64_t rows;
  int channels, groups;
  int64_t partial_rows;
};

template <typename T> SFGS_HD T biased(const T* bias, int channel, T value) {
  return bias ? value + bias[channel] : value;
}

template <typename T> SFGS_HD T inverse_deviation(T variance, T epsilon) {
  using std::sqrt;  // the host's, or CUDA's device overloads
  return T(1) / sqrt(variance + epsilon);
}

// The output of one element from its normalised value.
template <typename T> SFGS_HD T activated(T xhat, T gamma, T beta) {
  const T y = gamma * xhat + beta;
  return y > T(0) ? y : T(0);
}

// The gradient reaching the affine output y (ReLU's mask): zero where the output was clamped.
template <typename T> SFGS_HD T affine_gradient(T grad_out, T xhat, T gamma, T beta) {
  return gamma * xhat + beta > T(0) ? grad_out : T(0);
}

// h's gradient from gxhat and the group's means of gxhat (m1) and gxhat * xhat (m2).
template <typename T> SFGS_HD T normalised_gradient(T gxhat, T xhat, T rstd, T m1, T m2) {
  return rstd * (gxhat - m1 - xhat * m2);
}

// One row on the CPU (the CUDA kernels spread a row over a warp instead), with the two-pass variance.
template <typename T> void forward_row(const GroupNormArrays<T>& a, int64_t row) {
  const int size = a.channels / a.groups;
  const T* pre = a.pre + row * a.channels;
  T* out = a.out + row * a.channels;
  for (int g = 0; g < a.groups; ++g) {
    const int first = g * size;
    T sum = 0;
    for (int c = first; c < first + size; ++c) sum += biased(a.bias, c, pre[c]);
    const T mean = sum / T(size);
    T squares = 0;
    for (int c = first; c < first + size; ++c) {
      const T d = biased(a.bias, c, pre[c]) - mean;
      squares += d * d;
    }
    const T rstd = inverse_deviation(squares / T(size), a.epsilon);
    for (int c = first; c < first + size; ++c)
      out[c] = activated((biased(a.bias, c, pre[c]) - mean) * rstd, a.gamma[c], a.beta[c]);
    a.mean[row * a.groups + g] = mean;
    a.rstd[row * a.groups + g] = rstd;
  }
}

// One row's backward on the CPU, adding its column sums to `columns` (3 x channels).
template <typename T> void backward_row(const GroupNormGradientArrays<T>& a, int64_t row, T* columns) {
  const int size = a.channels / a.groups;
  const T* pre = a.pre + row * a.channels;
  const T* grad_out = a.grad_out + row * a.channels;
  T* grad_pre = a.grad_pre + row * a.channels;
  for (int g = 0; g < a.groups; ++g) {
    const int first = g * size;
    const T mean = a.mean[row * a.groups + g], rstd = a.rstd[row * a.groups + g];
    T m1 = 0, m2 = 0;
    for (int c = first; c < first + size; ++c) {
      const T xhat = (biased(a.bias, c, pre[c]) - mean) * rstd;
      const T gy = affine_gradient(grad_out[c], xhat, a.gamma[c], a.beta[c]);
      m1 += gy * a.gamma[c];
      m2 += gy * a.gamma[c] * xhat;
      columns[c] += gy * xhat;
      columns[a.channels + c] += gy;
    }
    m1 /= T(size);
    m2 /= T(size);
    for (int c = first; c < first + size; ++c) {
      const T xhat = (biased(a.bias, c, pre[c]) - mean) * rstd;
      const T gy = affine_gradient(grad_out[c], xhat, a.gamma[c], a.beta[c]);
      grad_pre[c] = normalised_gradient(gy * a.gamma[c], xhat, rstd, m1, m2);
      columns[2 * a.channels + c] += grad_pre[c];
    }
  }
}

}  // namespace sfgs::group_norm
