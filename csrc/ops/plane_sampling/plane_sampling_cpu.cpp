// CPU backend of the planes' backward (ops/plane_sampling/backend.h): the chunks in order, each adding its share.
#include "ops/plane_sampling/backend.h"

namespace sfgs::plane_sampling::cpu {
namespace {

template <typename T> void gradient_impl(const PlaneGradientArrays<T>& a) {
  for (int64_t k = 0; k < a.chunks; ++k)
    if (chunk_texel_valid(a, k))
      for (int64_t c = 0; c < a.channels; ++c) a.grad_planes[gradient_index(a, k, c)] += chunk_gradient(a, k, c);
}

}  // namespace

void gradient(const PlaneGradientArrays<float>& a) { gradient_impl(a); }
void gradient(const PlaneGradientArrays<double>& a) { gradient_impl(a); }

}  // namespace sfgs::plane_sampling::cpu
