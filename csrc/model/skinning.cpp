#include "model/skinning.h"

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/tensor_checks.h"
#include "common/constants.h"

namespace sfgs::model {

at::Tensor blend_transforms(const at::Tensor& weights, const at::Tensor& transforms) {
  TORCH_CHECK(weights.defined() && weights.dim() == 2, "blend_transforms: weights must have shape (N, J), got ",
              body::describe(weights));
  const int64_t n = weights.size(0), j = weights.size(1);
  TORCH_CHECK(transforms.defined() && transforms.sizes() == at::IntArrayRef({j, 4, 4}),
              "blend_transforms: transforms must have shape (", j, ", 4, 4), got ", body::describe(transforms));
  return weights.matmul(transforms.narrow(1, 0, 3).reshape({j, 12})).view({n, 3, 4});
}

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

at::Tensor vertex_normals(const at::Tensor& vertices, const at::Tensor& faces) {
  const at::Tensor v0 = vertices.index_select(0, faces.select(1, 0));
  const at::Tensor v1 = vertices.index_select(0, faces.select(1, 1));
  const at::Tensor v2 = vertices.index_select(0, faces.select(1, 2));
  const at::Tensor face_normals = at::linalg_cross(v1 - v0, v2 - v0, -1);  // length: twice the area
  at::Tensor sums = at::zeros_like(vertices);
  for (int64_t corner = 0; corner < 3; ++corner) sums.index_add_(0, faces.select(1, corner), face_normals);
  const at::Tensor length = sums.pow(2).sum(1, /*keepdim=*/true).sqrt();
  return at::where(length > kMinNormalLength, sums / length.clamp_min(kMinNormalLength), at::zeros_like(sums));
}

}  // namespace sfgs::model
