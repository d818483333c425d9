#include "model/skinning.h"

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

namespace sfgs::model {

at::Tensor transform_points(const at::Tensor& blended, const at::Tensor& points) {
  return (blended.narrow(2, 0, 3) * points.unsqueeze(1)).sum(-1) + blended.select(2, 3);
}

at::Tensor isotropic_covariances(const at::Tensor& blended, const at::Tensor& log_scales) {
  const at::Tensor a = blended.narrow(2, 0, 3);
  const at::Tensor gram = a.matmul(a.transpose(1, 2)).view({-1, 9});  // row-major A A^T
  const at::Tensor upper = at::stack({gram.select(1, 0), gram.select(1, 1), gram.select(1, 2), gram.select(1, 4),
                                      gram.select(1, 5), gram.select(1, 8)},
                                     1);
  return upper * (2 * log_scales).exp().unsqueeze(1);
}

}  // namespace sfgs::model
