#pragma once
// Rendering an avatar closer or larger than its training images. Its Gaussians were fitted at the training views'
// sampling, each widened on screen by the splatting's low-pass (kLowPassVariancePx2 square pixels), so many are far
// smaller than the gaps between them; seen at a finer sampling, that low-pass (a fixed size in pixels) shrinks in the
// world and the surface falls apart into dots and holes. As Mip-Splatting's 3D smoothing filter, each Gaussian keeps
// the blur of the finest sampling training gave it: an avatar's sampling record holds, per Gaussian, the smallest
// footprint (the world length of a pixel at its depth) any training view had of it, and a render that samples it more
// finely adds the difference as an isotropic variance in the world, so its low-pass and the added variance make the
// training's. A render at the training's sampling or coarser is left unchanged.
#include <ATen/core/Tensor.h>

#include "ops/splat/splat.h"
#include "ops/splat/constants.h"

namespace sfgs::model {

// Per Gaussian, the world length of one of `camera`'s pixels at its depth (depth / sqrt(fx fy)) where it is in view
// (beyond the near plane and projecting into the image), +inf elsewhere. means (N, 3) in the world. No gradient; no
// host synchronisation.
at::Tensor frame_footprint(const at::Tensor& means, const Camera& camera);

// The record an avatar keeps from the elementwise minimum of frame_footprint over its training steps (N): where no
// training view held a Gaussian (+inf), the median of the others (none held: 0, no filter). Checked: (N), floating,
// no NaN, non-negative.
at::Tensor sampling_record(const at::Tensor& minimum_footprint);

// covariances (N, 6: xx, xy, xz, yy, yz, zz) of Gaussians at means (N, 3) in the world, as `camera` sees them, with
// kLowPassVariancePx2 (F^2 - (z / f)^2) added to the diagonal where positive: F the record (N), z a mean's depth in
// the camera's frame and f = sqrt(fx fy). Differentiable in the covariances and means.
at::Tensor sampling_filtered(const at::Tensor& covariances, const at::Tensor& means, const Camera& camera,
                             const at::Tensor& record);

}  // namespace sfgs::model
