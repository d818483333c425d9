// CPU reference backend of the skinning op: skin_math.h's per-Gaussian steps in a parallel loop.
#include <algorithm>
#include <vector>

#include <ATen/Parallel.h>

#include "ops/skin/backend.h"

namespace sfgs::skin::cpu {
namespace {

constexpr int64_t kGrain = 2048;  // Gaussians per parallel task, and per chunk of the transforms' gradient

template <typename Arrays, typename Step> void for_each_gaussian(const Arrays& arrays, Step step) {
  at::parallel_for(0, arrays.count, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) step(arrays, i);
  });
}

template <typename T> void backward_of(const SkinGradientArrays<T>& g) {
  if (g.grad_transforms == nullptr)
    return for_each_gaussian(
        g, [](const SkinGradientArrays<T>& a, int64_t i) { skin_one_backward(a, i, [](int64_t, T) {}); });
  const int64_t values = g.joint_count * kTransformValues;
  const int64_t chunks = (g.count + kGrain - 1) / kGrain;
  std::vector<T> chunk_sums(size_t(chunks * values), T(0));
  at::parallel_for(0, chunks, 1, [&](int64_t first, int64_t last) {
    for (int64_t chunk = first; chunk < last; ++chunk) {
      T* sums = chunk_sums.data() + chunk * values;
      const int64_t end = std::min(g.count, (chunk + 1) * kGrain);
      for (int64_t i = chunk * kGrain; i < end; ++i)
        skin_one_backward(g, i, [&](int64_t value, T share) { sums[value] += share; });
    }
  });
  for (int64_t v = 0; v < values; ++v) {
    T sum = T(0);
    for (int64_t chunk = 0; chunk < chunks; ++chunk) sum += chunk_sums[size_t(chunk * values + v)];
    g.grad_transforms[v] = sum;
  }
}

}  // namespace

void forward(const SkinArrays<float>& a) { for_each_gaussian(a, skin_one<float>); }
void forward(const SkinArrays<double>& a) { for_each_gaussian(a, skin_one<double>); }
void backward(const SkinGradientArrays<float>& a) { backward_of(a); }
void backward(const SkinGradientArrays<double>& a) { backward_of(a); }

}  // namespace sfgs::skin::cpu
