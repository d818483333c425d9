#pragma once
// The silhouette term of `sfgs fit`, a chamfer between the person mask and the projected body that needs no
// renderer: (1) every sampled surface vertex must project inside the mask, penalised by the mask's distance
// transform at its projection (bilinear, so differentiable in the position), and (2) every sampled point of the mask's
// boundary must have a projected vertex near it (the mask covered). Both are robust (Geman-McClure) and measured in
// units of the person's size in the image, like the keypoint residuals. docs/fitting.md reports what it changes.
#include <ATen/core/Tensor.h>

#include <cstdint>
#include <vector>

#include "body/smplx.h"
#include "fit/fit_input.h"

namespace sfgs::fit {

struct SilhouetteTargets {
  at::Tensor outside_distance;   // (B, 1, H', W') distance in image pixels from each (reduced) pixel to the mask
  at::Tensor boundary;           // (B, M, 2) pixel positions of boundary samples
  at::Tensor boundary_weight;    // (B, M) 1 for a sample, 0 for padding and for frames without a mask
  at::Tensor frame_weight;       // (B) 1 for frames with a mask
  double width = 0, height = 0;  // the full image size the positions refer to
};

// Targets for the frames with masks; nullopt-like (undefined tensors) when no frame has one or the frames differ in
// size. Reads the masks once; the targets go to `options`' device.
SilhouetteTargets silhouette_targets(const FitInput& input, const at::TensorOptions& options);

// Evenly spread surface vertices of the body (every k-th of the vertices that no hand or eye joint dominates: the
// hands' silhouettes are thinner than the sample spacing), (N) int64.
at::Tensor silhouette_vertex_sample(const body::SmplxModelData& model, int64_t count);

// The two chamfer terms of projected sample vertices (B, N, 2), divided by the person size (B), summed, mean over
// the frames with masks.
at::Tensor silhouette_loss(const at::Tensor& projected, const SilhouetteTargets& targets, const at::Tensor& person_size,
                           double sigma);

// Exact Euclidean distance transform (Felzenszwalb & Huttenlocher) of a (H, W) bool mask: each pixel's distance in
// pixels to the nearest true pixel (0 on it; a large value everywhere when the mask is empty). CPU float32.
at::Tensor distance_to_mask(const at::Tensor& mask);

}  // namespace sfgs::fit
