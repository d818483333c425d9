#include "model/observation_prior.h"

#include <vector>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "body/tensor_checks.h"
#include "common/constants.h"

namespace sfgs::model {

at::Tensor frame_observation(const at::Tensor& means, const at::Tensor& normals, const at::Tensor& depth,
                             const Camera& camera) {
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && normals.sizes() == means.sizes(),
              "frame_observation: means and normals must be (N, 3) alike, got ", describe(means), " and ",
              describe(normals));
  TORCH_CHECK(depth.dim() == 2 && depth.size(0) == camera.height && depth.size(1) == camera.width,
              "frame_observation: depth must be (", camera.height, ", ", camera.width, "), got ", describe(depth));
  at::NoGradGuard no_grad;
  const auto options = means.options();
  const auto& m = camera.world_to_camera;
  // A camera at the origin (points given in its frame, as a training step gives them) needs no transform, and no
  // upload of one.
  at::Tensor p = means.detach(), n = normals.detach();
  if (!camera_at_origin(camera)) {
    const at::Tensor view = at::tensor(std::vector<double>(m.begin(), m.end()), at::kDouble).view({4, 4}).to(options);
    const at::Tensor rotation = view.slice(0, 0, 3).slice(1, 0, 3);
    p = p.matmul(rotation.t()) + view.slice(0, 0, 3).select(1, 3);
    n = n.matmul(rotation.t());
  }
  const at::Tensor z = p.select(1, 2);
  // The cosine between the normal and the direction to the camera (at the origin).
  const at::Tensor facing = -(n * p).sum(1) / p.norm(2, 1).clamp_min(kMinNormalLength);
  const at::Tensor safe_z = z.clamp_min(camera.near_plane);
  const at::Tensor u = camera.fx * p.select(1, 0) / safe_z + camera.cx;
  const at::Tensor v = camera.fy * p.select(1, 1) / safe_z + camera.cy;
  const at::Tensor inside = (z > camera.near_plane) & (u >= 0) & (u < double(camera.width)) & (v >= 0) &
                            (v < double(camera.height));
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
  const int64_t n = confidence.size(0);
  TORCH_CHECK(confidence.dim() == 1 && neighbours.counts.dim() == 1 && neighbours.counts.size(0) == n &&
                  neighbours.indices.dim() == 2 && neighbours.indices.size(0) == n,
              "propagate_from_observed: confidence (N) and neighbours of N points expected, got ", describe(confidence),
              " for ", neighbours.counts.size(0), " points");
  at::NoGradGuard no_grad;
  const auto options = confidence.options().dtype(dtype);
  PropagationPlan plan;
  plan.point_count = n;
  const at::Tensor known = confidence >= 1.0;
  plan.any_known = known.any().item<bool>();
  if (!plan.any_known) return plan;
  const int64_t k = neighbours.indices.size(1);
  const at::Tensor rows = neighbours.indices.to(confidence.device());  // (N, K)
  const at::Tensor indices = rows.reshape({-1});
  const at::Tensor counts = neighbours.counts.to(confidence.device());
  const at::Tensor slot_valid = (at::arange(k, counts.options()).unsqueeze(0) < counts.unsqueeze(1)).to(options);
  plan.trust = confidence.to(options).unsqueeze(1);
  plan.known = known.unsqueeze(1);
  plan.neighbours = indices;
  plan.slot_weight = slot_valid.unsqueeze(2);
  plan.divisor = counts.clamp_min(1).to(options).unsqueeze(1);

  // The front: each ring of unfilled points next to filled ones takes the mean of its filled neighbours.
  at::Tensor filled = known.to(options);
  while (true) {
    const at::Tensor filled_neighbours = filled.index_select(0, indices).view({n, k}) * slot_valid;
    const at::Tensor filled_count = filled_neighbours.sum(1);
    const at::Tensor reached = (filled == 0) & (filled_count > 0);
    const at::Tensor points = reached.nonzero().squeeze(1);
    if (points.size(0) == 0) break;
    PropagationPlan::Ring ring;
    ring.points = points;
    ring.neighbours = rows.index_select(0, points).reshape({-1});
    ring.filled = filled_neighbours.index_select(0, points).unsqueeze(2);
    ring.count = filled_count.index_select(0, points).clamp_min(1).unsqueeze(1);
    plan.rings.push_back(std::move(ring));
    filled = filled + reached.to(options);
  }
  plan.reached = (filled > 0).unsqueeze(1);
  return plan;
}

at::Tensor propagate_from_observed(const at::Tensor& values, const PropagationPlan& plan) {
  TORCH_CHECK(values.dim() == 2 && values.size(0) == plan.point_count,
              "propagate_from_observed: values (N, C) for the plan's ", plan.point_count, " points expected, got ",
              describe(values));
  if (!plan.any_known) return values;
  TORCH_CHECK(values.device() == plan.trust.device() && values.scalar_type() == plan.trust.scalar_type(),
              "propagate_from_observed: values on ", plan.trust.device(), " in ", plan.trust.scalar_type(),
              " expected (the plan's), got ", describe(values));
  at::NoGradGuard no_grad;
  const int64_t n = values.size(0), c = values.size(1), k = plan.slot_weight.size(1);
  at::Tensor x = values * plan.known;
  for (const PropagationPlan::Ring& ring : plan.rings) {
    const int64_t m = ring.points.size(0);
    const at::Tensor mean = (x.index_select(0, ring.neighbours).view({m, k, c}) * ring.filled).sum(1) / ring.count;
    x.index_copy_(0, ring.points, mean);
  }
  x = at::where(plan.reached, x, values);  // mesh parts without an observed point keep theirs
  // Smoothing: the propagated values relax towards the mean of their neighbours; the observed ones stay.
  for (int64_t pass = 0; pass < kObservationSmoothingPasses; ++pass)
    x = at::where(plan.known, x,
                  (x.index_select(0, plan.neighbours).view({n, k, c}) * plan.slot_weight).sum(1) / plan.divisor);
  return plan.trust * values + (1 - plan.trust) * x;
}

at::Tensor propagate_from_observed(const at::Tensor& values, const at::Tensor& confidence,
                                   const body::VertexNeighbours& neighbours) {
  TORCH_CHECK(values.dim() == 2 && confidence.dim() == 1 && confidence.size(0) == values.size(0),
              "propagate_from_observed: values (N, C), confidence (N) and neighbours of N points expected, got ",
              describe(values), " and ", describe(confidence), " for ", neighbours.counts.size(0), " points");
  return propagate_from_observed(values, plan_propagation(confidence.to(values.device()), neighbours,
                                                          values.scalar_type()));
}

}  // namespace sfgs::model
