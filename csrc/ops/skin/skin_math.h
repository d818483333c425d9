#pragma once
// Linear blend skinning of one isotropic Gaussian, written once for the CPU reference (float and double) and the CUDA
// kernel, with its vector-Jacobian product. A Gaussian's blended transform [A | t] = sum_k w_k T_{j_k} (the rows
// 0-2 of its joints' 4x4 transforms) carries its canonical mean x to A x + t and its covariance exp(2 s) I to
// exp(2 s) A A^T, stored packed (xx, xy, xz, yy, yz, zz) as sfgs::render takes it. The arrays both backends loop
// over and the per-Gaussian steps they take are here too, so the two cannot drift apart. No torch in here.
#include <cstdint>
#include <limits>

#include "ops/splat/pair_math.h"

namespace sfgs::skin {

using splat::Mat3;
using splat::Vec3;

// Rows 0-2 of a 4x4 transform, row-major: 12 values.
inline constexpr int kTransformValues = 12;

template <typename T> struct Blended {
  Mat3<T> a;  // column-major (glm): a[column][row]
  Vec3<T> t;
};

// The skinning-weighted blend of `influences` (joint, weight) pairs of a Gaussian's row; transforms (J, 12). A joint
// outside [0, J) makes the blend NaN (the op's kernels are reachable from torch.ops without the public checks).
template <typename T>
SFGS_HD Blended<T> blend(const int32_t* joints, const T* weights, int influences, const T* transforms,
                         int64_t joint_count) {
  Blended<T> b{Mat3<T>(T(0)), Vec3<T>(T(0))};
  for (int k = 0; k < influences; ++k) {
    const T w = weights[k];
    if (w == T(0)) continue;  // the padding of rows with fewer influences
    if (joints[k] < 0 || joints[k] >= joint_count) {
      const T nan = std::numeric_limits<T>::quiet_NaN();
      return Blended<T>{Mat3<T>(nan), Vec3<T>(nan)};
    }
    const T* m = transforms + int64_t(joints[k]) * kTransformValues;
    for (int row = 0; row < 3; ++row) {
      for (int col = 0; col < 3; ++col) b.a[col][row] += w * m[row * 4 + col];
      b.t[row] += w * m[row * 4 + 3];
    }
  }
  return b;
}

template <typename T> SFGS_HD Vec3<T> apply(const Blended<T>& b, const Vec3<T>& x) { return b.a * x + b.t; }

// exp(2 s) A A^T packed (xx, xy, xz, yy, yz, zz).
template <typename T> SFGS_HD void covariance(const Blended<T>& b, T log_scale, T* packed) {
  const T variance = splat::exp_of(T(2) * log_scale);
  const Mat3<T> gram = b.a * glm::transpose(b.a);  // symmetric
  packed[0] = variance * gram[0][0];
  packed[1] = variance * gram[1][0];
  packed[2] = variance * gram[2][0];
  packed[3] = variance * gram[1][1];
  packed[4] = variance * gram[2][1];
  packed[5] = variance * gram[2][2];
}

// d loss / d x = A^T g_mean.
template <typename T> SFGS_HD Vec3<T> mean_vjp(const Blended<T>& b, const Vec3<T>& grad_mean) {
  return glm::transpose(b.a) * grad_mean;
}

// d loss / d s = 2 sum_p g_p cov_p: the covariance is exp(2 s) times a matrix free of s.
template <typename T> SFGS_HD T log_scale_vjp(const T* packed_covariance, const T* grad_covariance) {
  T sum = T(0);
  for (int p = 0; p < 6; ++p) sum += grad_covariance[p] * packed_covariance[p];
  return T(2) * sum;
}

// Inputs and outputs of the forward pass as contiguous arrays of one floating type.
template <typename T> struct SkinArrays {
  const int32_t* joints;     // (N, K) influencing joints per Gaussian
  const T* weights;          // (N, K) their weights; 0 pads a row
  int influences;            // K
  int64_t count;             // N
  const T* transforms;       // (J, 12)
  int64_t joint_count;       // J
  const T* canonical_means;  // (N, 3)
  const T* log_scales;       // (N)
  const T* rest;             // (N, 3) points skinned without offsets, or null
  T* means;                  // (N, 3)
  T* covariances;            // (N, 6)
  T* posed_rest;             // (N, 3), written when rest is given
};

template <typename T> SFGS_HD void skin_one(const SkinArrays<T>& s, int64_t i) {
  const Blended<T> b =
      blend(s.joints + i * s.influences, s.weights + i * s.influences, s.influences, s.transforms, s.joint_count);
  const T* x = s.canonical_means + 3 * i;
  const Vec3<T> mean = apply(b, Vec3<T>(x[0], x[1], x[2]));
  for (int c = 0; c < 3; ++c) s.means[3 * i + c] = mean[c];
  covariance(b, s.log_scales[i], s.covariances + 6 * i);
  if (s.rest == nullptr) return;
  const T* r = s.rest + 3 * i;
  const Vec3<T> posed = apply(b, Vec3<T>(r[0], r[1], r[2]));
  for (int c = 0; c < 3; ++c) s.posed_rest[3 * i + c] = posed[c];
}

// The backward pass's arrays: the forward's weights and transforms, its covariances (saved), the output gradients
// (either may be null: no gradient reached that output) and the input gradients.
template <typename T> struct SkinGradientArrays {
  const int32_t* joints;
  const T* weights;
  int influences;
  int64_t count;
  const T* transforms;
  int64_t joint_count;
  const T* covariances;       // (N, 6) the forward's output
  const T* grad_means;        // (N, 3) or null
  const T* grad_covariances;  // (N, 6) or null
  const T* grad_posed_rest;   // (N, 3) or null
  T* grad_canonical_means;    // (N, 3)
  T* grad_log_scales;         // (N)
  T* grad_rest;               // (N, 3), written when grad_posed_rest is given
};

template <typename T> SFGS_HD void skin_one_backward(const SkinGradientArrays<T>& g, int64_t i) {
  Vec3<T> dx(T(0));
  if (g.grad_means != nullptr || g.grad_posed_rest != nullptr) {
    const Blended<T> b =
        blend(g.joints + i * g.influences, g.weights + i * g.influences, g.influences, g.transforms, g.joint_count);
    if (g.grad_means != nullptr) {
      const T* gm = g.grad_means + 3 * i;
      dx = mean_vjp(b, Vec3<T>(gm[0], gm[1], gm[2]));
    }
    if (g.grad_posed_rest != nullptr) {
      const T* gr = g.grad_posed_rest + 3 * i;
      const Vec3<T> dr = mean_vjp(b, Vec3<T>(gr[0], gr[1], gr[2]));
      for (int c = 0; c < 3; ++c) g.grad_rest[3 * i + c] = dr[c];
    }
  }
  for (int c = 0; c < 3; ++c) g.grad_canonical_means[3 * i + c] = dx[c];
  g.grad_log_scales[i] =
      g.grad_covariances != nullptr ? log_scale_vjp(g.covariances + 6 * i, g.grad_covariances + 6 * i) : T(0);
}

}  // namespace sfgs::skin
