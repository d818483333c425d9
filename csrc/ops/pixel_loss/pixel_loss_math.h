#pragma once
// The per-pixel image losses of training, written once for the CPU backend (float and double) and the CUDA kernels:
// for a prediction p and a target t (H, W, 3) in [0, 1], the sums of
//   |p - t|                           (L1),
//   |lab(p) - lab(t)|                 (L1 in CIELAB, D65, channels scaled by 1/100, 1/110, 1/110: train/losses.h),
//   |(p[x+1] - p[x]) - (t[x+1] - t[x])| and the same along y   (L1 of the image gradients),
// and the gradient of a weighted sum of their means with respect to p, pixel by pixel. The sRGB decoding clamps to
// [0, 1] (no gradient outside) and the CIELAB cube root has its linear branch at and below (6/29)^3, as
// train::rgb_to_lab. No torch in here.
#include <cmath>
#include <cstdint>

#include "ops/pixel_loss/constants.h"
#include "common/host_device.h"

namespace sfgs::pixel_loss {

inline constexpr int kSums = 4;  // L1, CIELAB L1, x-gradient L1, y-gradient L1

template <typename T> struct PixelLossArrays {
  const T* prediction;  // (H, W, 3)
  const T* target;      // (H, W, 3)
  T* partial_sums;      // (partials, kSums): each part's sums divided by the terms' counts (their sum: the means)
  int64_t partials;
  int height, width;
};

template <typename T> struct PixelLossGradientArrays {
  const T* prediction;
  const T* target;
  const T* weight;     // (kSums) on the arrays' device: d(objective) / d(mean of each term)
  T* grad_prediction;  // (H, W, 3)
  int height, width;
};

template <typename T> SFGS_HD T sign_of(T v) { return v > T(0) ? T(1) : (v < T(0) ? T(-1) : T(0)); }

template <typename T> struct Lab { T l, a, b; };

// sRGB -> linear, clamped into [0, 1]; `slope` is its derivative (0 where clamped).
template <typename T> SFGS_HD T srgb_to_linear(T c, T* slope) {
  using std::pow;
  const bool inside = c >= T(0) && c <= T(1);
  const T clamped = c < T(0) ? T(0) : (c > T(1) ? T(1) : c);
  if (clamped <= T(0.04045)) {
    *slope = inside ? T(1) / T(12.92) : T(0);
    return clamped / T(12.92);
  }
  const T base = (clamped + T(0.055)) / T(1.055);
  *slope = inside ? T(2.4) / T(1.055) * pow(base, T(1.4)) : T(0);
  return pow(base, T(2.4));
}

// CIELAB's f(t) and its derivative.
template <typename T> SFGS_HD T lab_f(T t, T* slope) {
  using std::cbrt;
  if (t > T(kLabLinearBelow)) {
    const T root = cbrt(t);
    *slope = T(1) / (T(3) * root * root);
    return root;
  }
  *slope = T(24389.0 / 27.0 / 116.0);
  return (T(24389.0 / 27.0) * t + T(16)) / T(116);
}

// The XYZ (normalised by the D65 white) of linear RGB: row k of the matrix.
template <typename T> SFGS_HD T xyz_row(int k, T r, T g, T b) {
  if (k == 0) return (T(0.412453) * r + T(0.357580) * g + T(0.180423) * b) / T(0.95047);
  if (k == 1) return T(0.212671) * r + T(0.715160) * g + T(0.072169) * b;
  return (T(0.019334) * r + T(0.119193) * g + T(0.950227) * b) / T(1.08883);
}

template <typename T> SFGS_HD T xyz_entry(int k, int c) {
  constexpr double m[3][3] = {{0.412453 / 0.95047, 0.357580 / 0.95047, 0.180423 / 0.95047},
                              {0.212671, 0.715160, 0.072169},
                              {0.019334 / 1.08883, 0.119193 / 1.08883, 0.950227 / 1.08883}};
  return T(m[k][c]);
}

// CIELAB of one pixel, and (when asked) the slopes of its sRGB decoding and of f per XYZ component.
template <typename T> SFGS_HD Lab<T> to_lab(const T* rgb, T (*linear_slopes)[3] = nullptr, T (*f_slopes)[3] = nullptr) {
  T lin_slope[3], lin[3];
  for (int c = 0; c < 3; ++c) lin[c] = srgb_to_linear(rgb[c], &lin_slope[c]);
  T f[3], f_slope[3];
  for (int k = 0; k < 3; ++k) f[k] = lab_f(xyz_row(k, lin[0], lin[1], lin[2]), &f_slope[k]);
  if (linear_slopes)
    for (int c = 0; c < 3; ++c) (*linear_slopes)[c] = lin_slope[c];
  if (f_slopes)
    for (int k = 0; k < 3; ++k) (*f_slopes)[k] = f_slope[k];
  return {(T(116) * f[1] - T(16)) / T(100), T(500) * (f[0] - f[1]) / T(110), T(200) * (f[1] - f[2]) / T(110)};
}

// d sum_k |lab_k(p) - lab_k(t)| / d p for one pixel, into grad[3].
template <typename T> SFGS_HD void lab_l1_gradient(const T* p, const T* t, T* grad) {
  T lin_slope[3], f_slope[3];
  const Lab<T> lp = to_lab(p, &lin_slope, &f_slope);
  const Lab<T> lt = to_lab(t);
  const T sl = sign_of(lp.l - lt.l), sa = sign_of(lp.a - lt.a), sb = sign_of(lp.b - lt.b);
  // Through L = (116 fy - 16) / 100, a = 500 (fx - fy) / 110, b = 200 (fy - fz) / 110.
  const T d_f[3] = {sa * T(500.0 / 110.0), sl * T(116.0 / 100.0) - sa * T(500.0 / 110.0) + sb * T(200.0 / 110.0),
                    -sb * T(200.0 / 110.0)};
  for (int c = 0; c < 3; ++c) {
    T d_lin = 0;
    for (int k = 0; k < 3; ++k) d_lin += d_f[k] * f_slope[k] * xyz_entry<T>(k, c);
    grad[c] = d_lin * lin_slope[c];
  }
}

template <typename T> SFGS_HD T lab_l1(const T* p, const T* t) {
  const Lab<T> lp = to_lab(p), lt = to_lab(t);
  using std::abs;
  return abs(lp.l - lt.l) + abs(lp.a - lt.a) + abs(lp.b - lt.b);
}

// Pixel (y, x)'s share of the four sums (its right and lower neighbours' differences included).
template <typename T> SFGS_HD void pixel_sums(const PixelLossArrays<T>& a, int y, int x, T (&sums)[kSums]) {
  using std::abs;
  const int64_t at = (int64_t(y) * a.width + x) * 3;
  const T* p = a.prediction + at;
  const T* t = a.target + at;
  sums[0] = abs(p[0] - t[0]) + abs(p[1] - t[1]) + abs(p[2] - t[2]);
  sums[1] = lab_l1(p, t);
  sums[2] = sums[3] = 0;
  for (int c = 0; c < 3; ++c) {
    if (x + 1 < a.width) sums[2] += abs((p[3 + c] - p[c]) - (t[3 + c] - t[c]));
    if (y + 1 < a.height) {
      const int64_t below = int64_t(a.width) * 3;
      sums[3] += abs((p[below + c] - p[c]) - (t[below + c] - t[c]));
    }
  }
}

// How many terms each mean averages.
template <typename T> SFGS_HD T term_count(int term, int height, int width) {
  const T pixels = T(height) * T(width) * T(3);
  if (term < 2) return pixels;
  return term == 2 ? T(height) * T(width - 1) * T(3) : T(height - 1) * T(width) * T(3);
}

// The gradient of sum_k weight_k mean_k at pixel (y, x).
template <typename T> SFGS_HD void pixel_gradient(const PixelLossGradientArrays<T>& a, int y, int x) {
  const int64_t row = int64_t(a.width) * 3, at = int64_t(y) * row + int64_t(x) * 3;
  const T* p = a.prediction + at;
  const T* t = a.target + at;
  T lab[3];
  lab_l1_gradient(p, t, lab);
  const T l1_scale = a.weight[0] / term_count<T>(0, a.height, a.width);
  const T lab_scale = a.weight[1] / term_count<T>(1, a.height, a.width);
  const T dx_scale = a.weight[2] / term_count<T>(2, a.height, a.width);
  const T dy_scale = a.weight[3] / term_count<T>(3, a.height, a.width);
  // A difference d = (p[right] - p[here]) - (...) pulls `here` by -sign(d) and `right` by +sign(d).
  const auto difference_sign = [&](int64_t from, int64_t to, int c) {
    return sign_of((a.prediction[to + c] - a.prediction[from + c]) - (a.target[to + c] - a.target[from + c]));
  };
  for (int c = 0; c < 3; ++c) {
    T g = l1_scale * sign_of(p[c] - t[c]) + lab_scale * lab[c];
    if (x + 1 < a.width) g -= dx_scale * difference_sign(at, at + 3, c);
    if (x > 0) g += dx_scale * difference_sign(at - 3, at, c);
    if (y + 1 < a.height) g -= dy_scale * difference_sign(at, at + row, c);
    if (y > 0) g += dy_scale * difference_sign(at - row, at, c);
    a.grad_prediction[at + c] = g;
  }
}

}  // namespace sfgs::pixel_loss
