#include "model/observation_prior.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "body/tensor_checks.h"
#include "body/constants.h"
#include "model/constants.h"
#include "ops/splat/camera_frame.h"

namespace sfgs::model {

at::Tensor frame_observation(const at::Tensor& means, const at::Tensor& normals, const at::Tensor& depth,
                             const Camera& camera) {
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && normals.sizes() == means.sizes(),
              "frame_observation: means and normals must be (N, 3) alike, got ", describe(means), " and ",
              describe(normals));
  TORCH_CHECK(depth.dim() == 2 && depth.size(0) == camera.height && depth.size(1) == camera.width,
              "frame_observation: depth must be (", camera.height, ", ", camera.width, "), got ", describe(depth));
  at::NoGradGuard no_grad;
  // A camera at the origin (points given in its frame, as a training step gives them) needs no transform, and no
  // upload of one.
  const at::Tensor p = points_in_camera_frame(means.detach(), camera);
  const at::Tensor n = directions_in_camera_frame(normals.detach(), camera);
  const at::Tensor z = p.select(1, 2);
  // The cosine between the normal and the direction to the camera (at the origin).
  const at::Tensor facing = -(n * p).sum(1) / p.norm(2, 1).clamp_min(kMinNormalLength);
  const PixelView view = pixel_view(p, camera);
  const at::Tensor &u = view.u, &v = view.v, &inside = view.inside;
  // Non-finite positions (a diverging run) are not inside; their pixel index must still be valid.
  const at::Tensor column = at::nan_to_num(u.floor(), 0, 0, 0).clamp(0, double(camera.width - 1)).to(at::kLong);
  const at::Tensor row = at::nan_to_num(v.floor(), 0, 0, 0).clamp(0, double(camera.height - 1)).to(at::kLong);
  const at::Tensor surface = depth.detach().reshape({-1}).index_select(0, row * camera.width + column).to(z.dtype());
  const at::Tensor seen = inside & (surface > 0) & (z <= surface + kObservationDepthTolerance) & (facing > 0);
  return at::where(seen, facing, at::zeros_like(facing));
}

at::Tensor observation_confidence(const at::Tensor& observed_fraction) {
  return (observed_fraction / kWellObservedFraction).clamp(0.0, 1.0);
}

PropagationPlan plan_propagation(const at::Tensor& confidence, const body::VertexNeighbours& neighbours,
                                 at::ScalarType dtype) {
  return mesh_propagation::plan(confidence, neighbours, confidence.device(), dtype);
}

at::Tensor propagate_from_observed(const at::Tensor& values, const PropagationPlan& plan) {
  return mesh_propagation::propagate(values, plan, kObservationSmoothingPasses);
}

at::Tensor propagate_from_observed(const at::Tensor& values, const at::Tensor& confidence,
                                   const body::VertexNeighbours& neighbours) {
  TORCH_CHECK(values.dim() == 2 && confidence.dim() == 1 && confidence.size(0) == values.size(0),
              "propagate_from_observed: values (N, C), confidence (N) and neighbours of N points expected, got ",
              describe(values), " and ", describe(confidence), " for ", neighbours.counts.size(0), " points");
  return propagate_from_observed(values,
                                 plan_propagation(confidence.to(values.device()), neighbours, values.scalar_type()));
}

}  // namespace sfgs::model
