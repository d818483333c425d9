// CPU backend of the fused SSIM: ssim_math.h's per-pixel steps around a separable window pass. The horizontal pass
// filters zero-padded rows into planar (maps, C, H, W) buffers; the vertical pass adds eleven of those rows into
// one output row. Both loop over the taps outside and the pixels inside, so the inner loops vectorise. One partial
// sum per row of a channel, so the result does not depend on the threads.
#include <algorithm>
#include <vector>

#include <ATen/Parallel.h>

#include "ops/ssim/backend.h"
#include "ops/ssim/constants.h"

namespace sfgs::ssim::cpu {
namespace {

constexpr int64_t kRowsPerTask = 8;  // rows of one channel per parallel task
constexpr int kMomentMaps = 5;       // mu_x, mu_y, xx, yy, xy

// out[j] = sum_k taps[k] padded[j + k] for j < count: the window over a line padded by kWindowRadius each side.
template <typename T> void filter_padded_line(const T* taps, const T* padded, int64_t count, T* out) {
  for (int64_t j = 0; j < count; ++j) out[j] = taps[0] * padded[j];
  for (int k = 1; k < kSsimWindowSize; ++k)
    for (int64_t j = 0; j < count; ++j) out[j] += taps[k] * padded[j + k];
}

// out = sum_k taps[k] rows[row + k - r] over the rows inside the image: the vertical pass of one output row of a
// planar (H, W) map, zero outside.
template <typename T>
void filter_column_window(const T* taps, const T* plane, int64_t height, int64_t width, int64_t row, T* out) {
  std::fill(out, out + width, T(0));
  for (int k = 0; k < kSsimWindowSize; ++k) {
    const int64_t source = row + k - kWindowRadius;
    if (source < 0 || source >= height) continue;
    const T* line = plane + source * width;
    for (int64_t j = 0; j < width; ++j) out[j] += taps[k] * line[j];
  }
}

template <typename T> void forward_images(const SsimArrays<T>& a) {
  const int64_t h = a.height, w = a.width, c = a.channels, plane = h * w;
  std::vector<T> rows(size_t(kMomentMaps * c * plane));
  at::parallel_for(0, c * h, kRowsPerTask, [&](int64_t begin, int64_t end) {
    const int64_t padded_width = w + 2 * kWindowRadius;
    std::vector<T> padded(size_t(kMomentMaps * padded_width), T(0));  // the zero margins stay zero
    for (int64_t task = begin; task < end; ++task) {
      const int64_t channel = task / h, row = task % h;
      for (int64_t j = 0; j < w; ++j) {
        const T x = a.prediction[(row * w + j) * c + channel], y = a.target[(row * w + j) * c + channel];
        const T products[kMomentMaps] = {x, y, x * x, y * y, x * y};
        for (int m = 0; m < kMomentMaps; ++m) padded[m * padded_width + kWindowRadius + j] = products[m];
      }
      for (int m = 0; m < kMomentMaps; ++m)
        filter_padded_line(a.taps, padded.data() + m * padded_width, w,
                           rows.data() + (m * c + channel) * plane + row * w);
    }
  });
  at::parallel_for(0, c * h, kRowsPerTask, [&](int64_t begin, int64_t end) {
    std::vector<T> moments(size_t(kMomentMaps * w));
    for (int64_t task = begin; task < end; ++task) {
      const int64_t channel = task / h, row = task % h;
      for (int m = 0; m < kMomentMaps; ++m)
        filter_column_window(a.taps, rows.data() + (m * c + channel) * plane, h, w, row, moments.data() + m * w);
      double sum = 0;  // a row's sum in double, so float32 loses nothing to the order of the pixels
      for (int64_t j = 0; j < w; ++j) {
        const Moments<T> m{moments[j], moments[w + j], moments[2 * w + j], moments[3 * w + j], moments[4 * w + j]};
        if (!a.derivative_maps) {
          sum += ssim_value(m, a.c1, a.c2);
          continue;
        }
        const PixelSsim<T> p = ssim_with_derivatives(m, a.c1, a.c2);
        sum += p.value;
        const int64_t at_pixel = channel * plane + row * w + j;
        a.derivative_maps[at_pixel] = p.d_mu_x;
        a.derivative_maps[c * plane + at_pixel] = p.d_xx;
        a.derivative_maps[2 * c * plane + at_pixel] = p.d_xy;
      }
      a.partial_sums[task] = T(sum);
    }
  });
}

template <typename T> void backward_images(const SsimGradientArrays<T>& a) {
  const int64_t h = a.height, w = a.width, c = a.channels, plane = h * w;
  // The derivative maps' planes are already planar: pad each row, filter it.
  std::vector<T> rows(size_t(kDerivativeMaps * c * plane));
  at::parallel_for(0, kDerivativeMaps * c * h, kRowsPerTask, [&](int64_t begin, int64_t end) {
    std::vector<T> padded(size_t(w + 2 * kWindowRadius), T(0));
    for (int64_t task = begin; task < end; ++task) {
      const T* line = a.derivative_maps + task * w;  // task = (map * C + channel) * H + row
      std::copy(line, line + w, padded.begin() + kWindowRadius);
      filter_padded_line(a.taps, padded.data(), w, rows.data() + task * w);
    }
  });
  const T scale = *a.grad_mean * a.inverse_count;
  at::parallel_for(0, c * h, kRowsPerTask, [&](int64_t begin, int64_t end) {
    std::vector<T> filtered(size_t(kDerivativeMaps * w));
    for (int64_t task = begin; task < end; ++task) {
      const int64_t channel = task / h, row = task % h;
      for (int m = 0; m < kDerivativeMaps; ++m)
        filter_column_window(a.taps, rows.data() + (m * c + channel) * plane, h, w, row, filtered.data() + m * w);
      for (int64_t j = 0; j < w; ++j) {
        const int64_t at_pixel = (row * w + j) * c + channel;
        a.grad_prediction[at_pixel] = prediction_gradient(scale, filtered[j], filtered[w + j], filtered[2 * w + j],
                                                          a.prediction[at_pixel], a.target[at_pixel]);
      }
    }
  });
}

}  // namespace

int64_t partial_sums(int64_t height, int64_t, int64_t channels) { return channels * height; }
void forward(const SsimArrays<float>& a) { forward_images(a); }
void forward(const SsimArrays<double>& a) { forward_images(a); }
void backward(const SsimGradientArrays<float>& a) { backward_images(a); }
void backward(const SsimGradientArrays<double>& a) { backward_images(a); }

}  // namespace sfgs::ssim::cpu
