#pragma once
// Linear blend skinning of one isotropic Gaussian, written once for the CPU reference (float and double) and the CUDA
// kernel, with its vector-Jacobian product. A Gaussian's blended transform [A | t] = sum_k w_k T_{j_k} (the rows
// 0-2 of its joints' 4x4 transforms) carries its canonical mean x to A x + t and its covariance exp(2 s) I to
// exp(2 s) A A^T, stored packed (xx, xy, xz, yy, yz, zz) as sfgs::render takes it. The arrays both backends loop
// over and the per-Gaussian steps they take are here too, so the two cannot drift apart. No torch in here.
//
// The transforms' gradient (a pose being fitted) is a sum over Gaussians into each joint's 12 values: every Gaussian
// gives d loss / d [A | t] once, and each of its influences adds it times its weight to its joint.
#include <cstdint>
#include <limits>

#include "ops/splat/pair_math.h"

namespace sfgs::skin {

using splat::Mat3;
using splat::Vec3;

// Rows 0-2 of a 4x4 transform, row-major: 12 values.
inline constexpr int kTransformValues = 12;
// Most joints whose transforms get a gradient: the CUDA kernel sums a block's share in shared memory (J x 12 values,
// 48 KiB in float64 at this count).
inline constexpr int64_t kMaxJointsWithTransformGradient = 512;

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
// (either may be null: no gradient reached that output) and the input gradients. The transforms' gradient is wanted
// when grad_transforms is set; it also reads the forward's inputs.
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
  const T* canonical_means;   // (N, 3), read when grad_transforms is set
  const T* log_scales;        // (N), read when grad_transforms is set
  const T* rest;              // (N, 3) or null, read when grad_transforms and grad_posed_rest are set
  T* grad_transforms;         // (J, 12) or null: summed by the backend from transform_vjp
};

// A point's share of d loss / d [A | t] (row-major 3 x 4): p = A x + t gives g x^T and g.
template <typename T> SFGS_HD void add_point_vjp(const T* grad, const T* point, T (&d)[kTransformValues]) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) d[4 * r + c] += grad[r] * point[c];
    d[4 * r + 3] += grad[r];
  }
}

// d loss / d [A | t] of Gaussian i's blended transform, row-major 3 x 4 as a transform's rows: its mean's and rest
// point's shares, and its covariance's: exp(2 s) H A, with H the symmetric matrix of the packed gradient whose
// diagonal is doubled (d (A A^T) = dA A^T + A dA^T, and the packed form holds each off-diagonal entry once).
template <typename T>
SFGS_HD void transform_vjp(const SkinGradientArrays<T>& g, int64_t i, const Blended<T>& b, T (&d)[kTransformValues]) {
  for (int v = 0; v < kTransformValues; ++v) d[v] = T(0);
  if (g.grad_means != nullptr) add_point_vjp(g.grad_means + 3 * i, g.canonical_means + 3 * i, d);
  if (g.grad_posed_rest != nullptr && g.rest != nullptr) add_point_vjp(g.grad_posed_rest + 3 * i, g.rest + 3 * i, d);
  if (g.grad_covariances == nullptr) return;
  const T* p = g.grad_covariances + 6 * i;
  const T h[3][3] = {{T(2) * p[0], p[1], p[2]}, {p[1], T(2) * p[3], p[4]}, {p[2], p[4], T(2) * p[5]}};
  const T variance = splat::exp_of(T(2) * g.log_scales[i]);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      T sum = T(0);
      for (int m = 0; m < 3; ++m) sum += h[r][m] * b.a[c][m];  // (H A)[r][c]; glm is column-major
      d[4 * r + c] += variance * sum;
    }
}

// Gaussian i's input gradients; with grad_transforms set, `add(value_index, value)` receives each of its influences'
// share of the transforms' gradient (value_index into the (J, 12) sums).
template <typename T, typename AddToTransforms>
SFGS_HD void skin_one_backward(const SkinGradientArrays<T>& g, int64_t i, AddToTransforms add) {
  const bool transforms_wanted = g.grad_transforms != nullptr;
  Vec3<T> dx(T(0));
  if (g.grad_means != nullptr || g.grad_posed_rest != nullptr || transforms_wanted) {
    const int32_t* joints = g.joints + i * g.influences;
    const T* weights = g.weights + i * g.influences;
    const Blended<T> b = blend(joints, weights, g.influences, g.transforms, g.joint_count);
    if (g.grad_means != nullptr) {
      const T* gm = g.grad_means + 3 * i;
      dx = mean_vjp(b, Vec3<T>(gm[0], gm[1], gm[2]));
    }
    if (g.grad_posed_rest != nullptr) {
      const T* gr = g.grad_posed_rest + 3 * i;
      const Vec3<T> dr = mean_vjp(b, Vec3<T>(gr[0], gr[1], gr[2]));
      for (int c = 0; c < 3; ++c) g.grad_rest[3 * i + c] = dr[c];
    }
    if (transforms_wanted) {
      T d[kTransformValues];
      transform_vjp(g, i, b, d);
      for (int k = 0; k < g.influences; ++k) {
        const T w = weights[k];
        // A joint out of range (its Gaussian's blend and gradients are NaN) has no row to add to.
        if (w == T(0) || joints[k] < 0 || joints[k] >= g.joint_count) continue;
        for (int v = 0; v < kTransformValues; ++v) add(int64_t(joints[k]) * kTransformValues + v, w * d[v]);
      }
    }
  }
  for (int c = 0; c < 3; ++c) g.grad_canonical_means[3 * i + c] = dx[c];
  g.grad_log_scales[i] =
      g.grad_covariances != nullptr ? log_scale_vjp(g.covariances + 6 * i, g.grad_covariances + 6 * i) : T(0);
}

}  // namespace sfgs::skin
