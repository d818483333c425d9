#pragma once
// Linear blend skinning of Gaussians: every point gets the skinning-weighted blend [A | t] of its joints'
// transforms (body::blend_transforms); its mean maps to A mu + t and its covariance to A Sigma A^T (A is the
// deformation's Jacobian, not a rotation in general).
#include <ATen/core/Tensor.h>

namespace sfgs::model {

// blended (N, 3, 4), points (N, 3) -> (N, 3).
at::Tensor transform_points(const at::Tensor& blended, const at::Tensor& points);

// Isotropic Gaussians exp(log_scales)^2 I (N) carried by the blended transforms: (N, 6) packed
// (xx, xy, xz, yy, yz, zz) of exp(2 s) A A^T, as sfgs::render takes covariances.
at::Tensor isotropic_covariances(const at::Tensor& blended, const at::Tensor& log_scales);

}  // namespace sfgs::model
