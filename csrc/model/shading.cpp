#include "model/shading.h"

#include <ATen/Functions.h>

namespace sfgs::model {

ShadingImpl::ShadingImpl() {
  at::Tensor start = at::zeros({kBasisSize, 3});
  start[0].fill_(1.0);
  coefficients_ = register_parameter("coefficients", start);
}

at::Tensor ShadingImpl::basis(const at::Tensor& normals) {
  const at::Tensor x = normals.select(1, 0), y = normals.select(1, 1), z = normals.select(1, 2);
  return at::stack({at::ones_like(x), y, z, x, x * y, y * z, 3.0 * z * z - 1.0, x * z, x * x - y * y}, 1);
}

at::Tensor ShadingImpl::forward(const at::Tensor& normals) const {
  TORCH_CHECK(normals.dim() == 2 && normals.size(1) == 3, "Shading: normals must be (N, 3), got ", normals.sizes());
  // Light is never negative: a clamped factor keeps a surface facing away from every light black, not inverted.
  return basis(normals.to(coefficients_.scalar_type())).matmul(coefficients_).clamp_min(0.0);
}

}  // namespace sfgs::model
