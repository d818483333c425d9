#pragma once
// The fused SSIM (ops/ssim/ssim.h), written once for the CPU backend (float and double) and the CUDA kernels: the
// arrays both walk, the Gaussian window and the per-pixel steps. Per channel, with G the 11 x 11 Gaussian window
// applied with zero padding (so every filtered map is H x W), x the prediction and y the target:
//   mu_x = G x, mu_y = G y, xx = G x^2, yy = G y^2, xy = G (x y),
//   A1 = 2 mu_x mu_y + C1, A2 = 2 (xy - mu_x mu_y) + C2,
//   B1 = mu_x^2 + mu_y^2 + C1, B2 = (xx - mu_x^2) + (yy - mu_y^2) + C2,
//   S = A1 A2 / (B1 B2), and the op's value is the mean of S over pixels and channels (N values).
// The gradient of that mean in x: the map's partial derivatives in the moments that depend on x,
//   dS/dmu_x = (2 mu_y (A2 - A1) - 2 mu_x S (B2 - B1)) / (B1 B2),  dS/dxx = -S / B2,  dS/dxy = 2 A1 / (B1 B2),
// reach pixel p through every window that covers it: dmean/dx_p = (G dS/dmu_x + 2 x_p G dS/dxx + y_p G dS/dxy) / N,
// where G applied again is the adjoint of the zero-padded filter because the window is symmetric. The forward
// writes the three derivative maps, the backward filters them and combines. No torch in here.
#include <array>
#include <cmath>
#include <cstdint>

#include "common/constants.h"
#include "common/host_device.h"
#include "ops/ssim/constants.h"

namespace sfgs::ssim {

inline constexpr int kWindowRadius = kSsimWindowSize / 2;

// The derivative maps are planar, (kDerivativeMaps, C, H, W): dS/dmu_x, dS/dxx, dS/dxy.
inline constexpr int kDerivativeMaps = 3;

// The forward's inputs and outputs. Images are (H, W, C) contiguous; partial_sums holds sums of S over the pixels
// the backend gave each entry (the op adds them up); derivative_maps is null when no gradient is wanted.
template <typename T> struct SsimArrays {
  const T* prediction;
  const T* target;
  T* partial_sums;
  T* derivative_maps;  // (3, C, H, W) or null
  int height, width, channels;
  T taps[kSsimWindowSize];
  T c1, c2;
};

// The backward's: the gradient of the op's scalar value (a device scalar: no host read) scaled by 1 / N, the
// forward's derivative maps filtered again and combined with the images into the prediction's gradient.
template <typename T> struct SsimGradientArrays {
  const T* prediction;
  const T* target;
  const T* derivative_maps;  // (3, C, H, W)
  const T* grad_mean;        // the gradient of the mean SSIM, one value
  T* grad_prediction;        // (H, W, C)
  int height, width, channels;
  T taps[kSsimWindowSize];
  T inverse_count;  // 1 / (H W C)
};

// The normalised 1D Gaussian g[i] ~ exp(-(i - r)^2 / (2 sigma^2)), in float64 whatever the images' dtype (the
// evaluation metric, metrics/image_metrics.cpp, filters with the same taps).
inline std::array<double, kSsimWindowSize> gaussian_window() {
  std::array<double, kSsimWindowSize> taps{};
  double sum = 0.0;
  for (int i = 0; i < kSsimWindowSize; ++i) {
    const int offset = i - kWindowRadius;
    taps[i] = std::exp(-double(offset * offset) / (2.0 * kSsimSigma * kSsimSigma));
    sum += taps[i];
  }
  for (double& t : taps) t /= sum;
  return taps;
}

// C1 = (K1 L)^2 and C2 = (K2 L)^2 for the data range L of images in [0, 1].
inline double ssim_c1() { return (kSsimK1 * kImageDataRange) * (kSsimK1 * kImageDataRange); }
inline double ssim_c2() { return (kSsimK2 * kImageDataRange) * (kSsimK2 * kImageDataRange); }

// The five filtered moments of one pixel and channel.
template <typename T> struct Moments { T mu_x, mu_y, xx, yy, xy; };

// The map's value and its derivatives in the moments the prediction moves.
template <typename T> struct PixelSsim { T value, d_mu_x, d_xx, d_xy; };

// S of one pixel, grouped as metrics::ssim_map writes it so that the two agree to rounding.
template <typename T> SFGS_HD T ssim_value(const Moments<T>& m, T c1, T c2) {
  const T mu_x2 = m.mu_x * m.mu_x, mu_y2 = m.mu_y * m.mu_y, mu_xy = m.mu_x * m.mu_y;
  const T var_x = m.xx - mu_x2, var_y = m.yy - mu_y2, cov_xy = m.xy - mu_xy;
  return (T(2) * mu_xy + c1) * (T(2) * cov_xy + c2) / ((mu_x2 + mu_y2 + c1) * (var_x + var_y + c2));
}

// S of one pixel with its derivatives in mu_x, xx and xy.
template <typename T> SFGS_HD PixelSsim<T> ssim_with_derivatives(const Moments<T>& m, T c1, T c2) {
  const T mu_x2 = m.mu_x * m.mu_x, mu_y2 = m.mu_y * m.mu_y, mu_xy = m.mu_x * m.mu_y;
  const T a1 = T(2) * mu_xy + c1, a2 = T(2) * (m.xy - mu_xy) + c2;
  const T b1 = mu_x2 + mu_y2 + c1, b2 = (m.xx - mu_x2) + (m.yy - mu_y2) + c2;
  const T inverse_denominator = T(1) / (b1 * b2);
  PixelSsim<T> p;
  p.value = ssim_value(m, c1, c2);
  p.d_mu_x = (T(2) * m.mu_y * (a2 - a1) - T(2) * m.mu_x * p.value * (b2 - b1)) * inverse_denominator;
  p.d_xx = -p.value / b2;
  p.d_xy = T(2) * a1 * inverse_denominator;
  return p;
}

// The prediction's gradient at a pixel from the filtered derivative maps there (times the scale dL/dmean / N).
template <typename T>
SFGS_HD T prediction_gradient(T scale, T filtered_d_mu_x, T filtered_d_xx, T filtered_d_xy, T x, T y) {
  return scale * (filtered_d_mu_x + T(2) * x * filtered_d_xx + y * filtered_d_xy);
}

}  // namespace sfgs::ssim
