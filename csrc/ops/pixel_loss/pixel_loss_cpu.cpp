// CPU backend of the fused pixel-loss op: pixel_loss_math.h's pixel steps, a row per parallel task; the forward's
// partial sums are one row each, so the result does not depend on the threads.
#include <ATen/Parallel.h>

#include "ops/pixel_loss/backend.h"

namespace sfgs::pixel_loss::cpu {
namespace {

template <typename T> void forward_rows(const PixelLossArrays<T>& a) {
  at::parallel_for(0, a.height, 1, [&](int64_t begin, int64_t end) {
    for (int64_t y = begin; y < end; ++y) {
      T row[kSums] = {0, 0, 0, 0};
      for (int x = 0; x < a.width; ++x) {
        T sums[kSums];
        pixel_sums(a, int(y), x, sums);
        for (int k = 0; k < kSums; ++k) row[k] += sums[k];
      }
      for (int k = 0; k < kSums; ++k) a.partial_sums[y * kSums + k] = row[k] / term_count<T>(k, a.height, a.width);
    }
  });
}

template <typename T> void backward_rows(const PixelLossGradientArrays<T>& a) {
  at::parallel_for(0, a.height, 1, [&](int64_t begin, int64_t end) {
    for (int64_t y = begin; y < end; ++y)
      for (int x = 0; x < a.width; ++x) pixel_gradient(a, int(y), x);
  });
}

}  // namespace

int64_t partials(int height) { return height; }
void forward(const PixelLossArrays<float>& a) { forward_rows(a); }
void forward(const PixelLossArrays<double>& a) { forward_rows(a); }
void backward(const PixelLossGradientArrays<float>& a) { backward_rows(a); }
void backward(const PixelLossGradientArrays<double>& a) { backward_rows(a); }

}  // namespace sfgs::pixel_loss::cpu
