#pragma once
// Surface the training video never or rarely showed: its Gaussians were fitted by no pixel, so the features they
// read are whatever other, observed points trained into the shared planes (the back of the head shows the face's
// texture). The prior replaces what was learned there by what the observed surface around it suggests, in
// proportion to how poorly it was observed. docs/avatar.md, "Surface the video never showed".
#include <ATen/core/Tensor.h>

#include "body/mesh.h"
#include "ops/mesh_propagation/mesh_propagation.h"
#include "ops/splat/splat.h"
#include "model/constants.h"

namespace sfgs::model {

// Per Gaussian, whether this training frame observed it, weighted by how squarely it faced the camera: in [0, 1],
// 0 unless it faces the camera, projects into the image and lies within kObservationDepthTolerance of the rendered
// depth at its pixel (nothing nearer hides it). means and normals (N, 3) world; depth (H, W) the render's.
// No gradient; no host synchronisation.
at::Tensor frame_observation(const at::Tensor& means, const at::Tensor& normals, const at::Tensor& depth,
                             const Camera& camera);

// Trust in each Gaussian's learned attributes, from the share of training steps that observed it: in [0, 1], 1 from
// kWellObservedFraction on.
at::Tensor observation_confidence(const at::Tensor& observed_fraction);

// The propagation below as a fixed plan (ops/mesh_propagation/mesh_propagation.h): which points the front from the
// well-observed surface reaches in which ring depends on the confidence alone, so it is found once per observation
// record (on the host) and every frame applies it without a host read (a CUDA graph records the application).
using PropagationPlan = mesh_propagation::Plan;

// The plan for confidence c (N) in [0, 1] over the mesh's neighbours, its tensors on c's device in `dtype`.
PropagationPlan plan_propagation(const at::Tensor& confidence, const body::VertexNeighbours& neighbours,
                                 at::ScalarType dtype);

// values (N, C) per mesh point, blended towards values propagated over the mesh from well-observed points:
// confidence c (N) in [0, 1]; a front from the points with c = 1 fills the rest ring by ring with the mean of their
// filled neighbours, kObservationSmoothingPasses smoothing passes blend it, and each point returns
// c v + (1 - c) propagated. Unchanged when no point is well observed. No host read, no gradient.
at::Tensor propagate_from_observed(const at::Tensor& values, const PropagationPlan& plan);
// The same, planned for this one call.
at::Tensor propagate_from_observed(const at::Tensor& values, const at::Tensor& confidence,
                                   const body::VertexNeighbours& neighbours);

}  // namespace sfgs::model
