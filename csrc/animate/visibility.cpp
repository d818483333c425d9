#include "animate/visibility.h"

#include <ATen/ATen.h>

#include "common/tensor_description.h"

namespace sfgs::animate {

at::Tensor cull_back_facing(const at::Tensor& opacities, const at::Tensor& means, const at::Tensor& normals,
                            const at::Tensor& centre, double max_cosine) {
  TORCH_CHECK(means.defined() && means.dim() == 2 && means.size(1) == 3 && at::isFloatingType(means.scalar_type()),
              "cull_back_facing: means must be a floating (N, 3) tensor, got ", describe(means));
  const int64_t n = means.size(0);
  TORCH_CHECK(normals.defined() && normals.sizes() == means.sizes() && normals.device() == means.device(),
              "cull_back_facing: normals must be an (", n, ", 3) tensor on ", means.device(), ", got ",
              describe(normals));
  TORCH_CHECK(
      opacities.defined() && opacities.dim() == 1 && opacities.size(0) == n && opacities.device() == means.device(),
      "cull_back_facing: opacities must be an (", n, ") tensor on ", means.device(), ", got ", describe(opacities));
  TORCH_CHECK(centre.defined() && centre.numel() == 3 && centre.device() == means.device(),
              "cull_back_facing: the camera centre must be a (3) tensor on ", means.device(), ", got ",
              describe(centre));
  if (max_cosine >= 1) return opacities;
  const at::Tensor ray = means - centre.reshape({1, 3}).to(means.scalar_type());
  const at::Tensor facing = (normals * ray).sum(1);
  const at::Tensor front = facing <= ray.norm(2, 1) * max_cosine;
  return opacities * front.to(opacities.scalar_type());
}

}  // namespace sfgs::animate
