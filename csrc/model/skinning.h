#pragma once
// Linear blend skinning of Gaussians: every point gets the skinning-weighted blend [A | t] of its joints'
// transforms; its mean maps to A mu + t and its covariance to A Sigma A^T (A is the deformation's Jacobian, not a
// rotation in general). Plus the posed mesh's vertex normals that the colour offset reads.
#include <ATen/core/Tensor.h>

namespace sfgs::model {

// weights (N, J), transforms (J, 4, 4) -> (N, 3, 4): the blended top three rows.
at::Tensor blend_transforms(const at::Tensor& weights, const at::Tensor& transforms);

// blended (N, 3, 4), points (N, 3) -> (N, 3).
at::Tensor transform_points(const at::Tensor& blended, const at::Tensor& points);

// Isotropic Gaussians exp(log_scales)^2 I (N) carried by the blended transforms: (N, 6) packed
// (xx, xy, xz, yy, yz, zz) of exp(2 s) A A^T, as sfgs::render takes covariances.
at::Tensor isotropic_covariances(const at::Tensor& blended, const at::Tensor& log_scales);

// Area-weighted unit vertex normals (N, 3) of the mesh vertices (N, 3), faces (F, 3) int64 (counter-clockwise
// seen from outside); vertices on no face, or only on degenerate ones, get 0.
at::Tensor vertex_normals(const at::Tensor& vertices, const at::Tensor& faces);

}  // namespace sfgs::model
