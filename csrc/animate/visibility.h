#pragma once
// What a frame need not splat: the Gaussians on the far side of the body. The body is a closed surface seen from
// outside, so a point whose posed surface normal faces away from the camera lies behind the near side along its
// view ray, and the near side's opaque Gaussians hide it. Culling them halves what a frame projects, bins, sorts
// and blends. Near the silhouette both sides face the camera edge-on, so only points facing away by more than a
// margin are culled (the cosine between the normal and the view ray above max_cosine); the learned offsets move a
// Gaussian a few millimetres off the surface, which that margin absorbs. It is still lossy on trained avatars (the
// antialiasing compensation scales small Gaussians' opacity down, so the near side does not hide the far side
// completely): the Animator keeps it off unless asked. bench_animate reports its run time against its error;
// docs/performance.md has the figures.
#include <ATen/core/Tensor.h>

#include "ops/splat/splat.h"

namespace sfgs::animate {

// opacities (N) with those of back-facing Gaussians set to zero (splatting then skips them): means and normals
// (N, 3) world, normals of unit length; camera_centre (3) on their device (sfgs::camera_centre) (a tensor, so a
// recorded CUDA graph reads the current camera); max_cosine >= 1 culls nothing. No host synchronisation.
at::Tensor cull_back_facing(const at::Tensor& opacities, const at::Tensor& means, const at::Tensor& normals,
                            const at::Tensor& camera_centre, double max_cosine);

}  // namespace sfgs::animate
