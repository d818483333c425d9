// CPU reference backend of the skinning op: skin_math.h's per-Gaussian steps in a parallel loop.
#include <ATen/Parallel.h>

#include "ops/skin/backend.h"

namespace sfgs::skin::cpu {
namespace {

constexpr int64_t kGrain = 2048;  // Gaussians per parallel task

template <typename Arrays, typename Step> void for_each_gaussian(const Arrays& arrays, Step step) {
  at::parallel_for(0, arrays.count, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) step(arrays, i);
  });
}

}  // namespace

void forward(const SkinArrays<float>& a) { for_each_gaussian(a, skin_one<float>); }
void forward(const SkinArrays<double>& a) { for_each_gaussian(a, skin_one<double>); }
void backward(const SkinGradientArrays<float>& a) { for_each_gaussian(a, skin_one_backward<float>); }
void backward(const SkinGradientArrays<double>& a) { for_each_gaussian(a, skin_one_backward<double>); }

}  // namespace sfgs::skin::cpu
