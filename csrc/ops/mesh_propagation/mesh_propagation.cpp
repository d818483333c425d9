// The mesh propagation: its plan (a breadth-first front on the host), validation at the boundary, the backend by
// device.
#include "ops/mesh_propagation/mesh_propagation.h"

#include <algorithm>
#include <limits>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "common/tensor_description.h"
#include "ops/mesh_propagation/backend.h"

namespace sfgs::mesh_propagation {
namespace {

// The ring of a point that no front reaches (its part of the mesh holds no trusted point).
constexpr int32_t kUnreached = std::numeric_limits<int32_t>::max();

template <typename T> at::Tensor propagate_as(const at::Tensor& values, const Plan& plan, int64_t passes) {
  const at::Tensor filled = values.clone(), scratch = at::empty_like(values), out = at::empty_like(values);
  PropagationArrays<T> a;
  a.neighbours = plan.neighbours.data_ptr<int32_t>();
  a.counts = plan.counts.data_ptr<int32_t>();
  a.ring_points = plan.ring_points.data_ptr<int32_t>();
  a.ring_sources = plan.ring_sources.data_ptr<int32_t>();
  a.ring_source_counts = plan.ring_source_counts.data_ptr<int32_t>();
  a.free_points = plan.free_points.data_ptr<int32_t>();
  a.point_count = plan.point_count;
  a.free_count = plan.free_points.size(0);
  a.slots = int(plan.neighbours.size(1));
  a.channels = int(values.size(1));
  a.values = values.data_ptr<T>();
  a.trust = plan.trust.data_ptr<T>();
  a.filled = filled.data_ptr<T>();
  a.scratch = scratch.data_ptr<T>();
  a.out = out.data_ptr<T>();
  if (values.is_cuda())
    cuda::propagate(a, plan.ring_offsets, passes, values.device());
  else
    cpu::propagate(a, plan.ring_offsets, passes);
  return out;
}

}  // namespace

int64_t Plan::widest_ring() const {
  int64_t widest = 0;
  for (size_t r = 1; r < ring_offsets.size(); ++r) widest = std::max(widest, ring_offsets[r] - ring_offsets[r - 1]);
  return widest;
}

Plan plan(const at::Tensor& trust, const body::VertexNeighbours& neighbours, at::Device device, at::ScalarType dtype) {
  TORCH_CHECK(trust.defined() && trust.dim() == 1 && at::isFloatingType(trust.scalar_type()),
              "mesh_propagation::plan: trust must be a floating (N) tensor, got ", describe(trust));
  const int64_t n = trust.size(0);
  TORCH_CHECK(neighbours.indices.defined() && neighbours.indices.dim() == 2 && neighbours.indices.size(0) == n &&
                  neighbours.counts.defined() && neighbours.counts.dim() == 1 && neighbours.counts.size(0) == n,
              "mesh_propagation::plan: the neighbours of the trust's ", n, " points expected, got indices ",
              describe(neighbours.indices), " and counts ", describe(neighbours.counts));
  TORCH_CHECK(n < std::numeric_limits<int32_t>::max(), "mesh_propagation::plan: at most 2^31 - 2 points, got ", n);
  TORCH_CHECK(dtype == at::kFloat || dtype == at::kDouble,
              "mesh_propagation::plan: the values' dtype must be float32 or float64, got ", dtype);
  at::NoGradGuard no_grad;
  const at::Tensor host_trust = trust.detach().to(at::kCPU, at::kDouble).contiguous();
  TORCH_CHECK(host_trust.isfinite().all().item<bool>(), "mesh_propagation::plan: the trust holds non-finite values");
  const at::Tensor indices = neighbours.indices.to(at::kCPU, at::kInt).contiguous();
  const at::Tensor counts = neighbours.counts.to(at::kCPU, at::kInt).contiguous();
  const int64_t k = indices.size(1);
  const int32_t* around = indices.data_ptr<int32_t>();
  const int32_t* count = counts.data_ptr<int32_t>();
  for (int64_t p = 0; p < n; ++p) {
    TORCH_CHECK(count[p] >= 0 && count[p] <= k, "mesh_propagation::plan: point ", p, " has ", count[p],
                " neighbours for ", k, " slots");
    for (int64_t s = 0; s < count[p]; ++s)
      TORCH_CHECK(around[p * k + s] >= 0 && around[p * k + s] < n, "mesh_propagation::plan: point ", p,
                  " names neighbour ", around[p * k + s], " outside [0, ", n, ")");
  }

  Plan plan;
  plan.point_count = n;
  const double* t = host_trust.data_ptr<double>();
  std::vector<int32_t> ring_of(size_t(n), kUnreached), pending, free_points;
  for (int64_t p = 0; p < n; ++p) {
    if (t[p] >= 1.0)
      ring_of[size_t(p)] = 0;
    else
      free_points.push_back(int32_t(p)), pending.push_back(int32_t(p));
  }
  plan.any_trusted = pending.size() < size_t(n);
  if (!plan.any_trusted) return plan;
  // The front: ring r takes the pending points with a neighbour of ring <= r (filled before it), and remembers
  // those neighbours.
  std::vector<int32_t> ring_points, ring_sources, ring_source_counts, still_pending;
  std::vector<int32_t> sources(static_cast<size_t>(k));
  for (int32_t ring = 0; !pending.empty(); ++ring) {
    const size_t start = ring_points.size();
    still_pending.clear();
    for (int32_t p : pending) {
      int32_t found = 0;
      for (int64_t s = 0; s < count[p]; ++s)
        if (ring_of[size_t(around[p * k + s])] <= ring) sources[size_t(found++)] = around[p * k + s];
      if (found == 0) {
        still_pending.push_back(p);
        continue;
      }
      ring_points.push_back(p);
      ring_source_counts.push_back(found);
      for (int64_t s = 0; s < k; ++s) ring_sources.push_back(s < found ? sources[size_t(s)] : p);
    }
    if (ring_points.size() == start) break;
    for (size_t i = start; i < ring_points.size(); ++i) ring_of[size_t(ring_points[i])] = ring + 1;
    plan.ring_offsets.push_back(int64_t(ring_points.size()));
    pending.swap(still_pending);
  }
  const auto on_device = [&](const std::vector<int32_t>& v) {
    return at::tensor(v, at::TensorOptions().dtype(at::kInt)).to(device);
  };
  plan.neighbours = indices.to(device);
  plan.counts = counts.to(device);
  plan.ring_points = on_device(ring_points);
  plan.ring_sources = on_device(ring_sources).view({int64_t(ring_source_counts.size()), k});
  plan.ring_source_counts = on_device(ring_source_counts);
  plan.free_points = on_device(free_points);
  plan.trust = host_trust.clamp(0.0, 1.0).to(device, dtype);
  return plan;
}

at::Tensor propagate(const at::Tensor& values, const Plan& plan, int64_t smoothing_passes) {
  TORCH_CHECK(values.defined() && values.dim() == 2 && values.size(0) == plan.point_count && values.size(1) >= 1,
              "mesh_propagation::propagate: values (N, C) for the plan's ", plan.point_count, " points expected, got ",
              describe(values));
  TORCH_CHECK(smoothing_passes >= 0, "mesh_propagation::propagate: smoothing passes must be >= 0, got ",
              smoothing_passes);
  if (!plan.any_trusted) return values;
  TORCH_CHECK(values.device() == plan.trust.device() && values.scalar_type() == plan.trust.scalar_type(),
              "mesh_propagation::propagate: values on ", plan.trust.device(), " in ", plan.trust.scalar_type(),
              " expected (the plan's), got ", describe(values));
  TORCH_CHECK(!values.is_cuda() || cuda::available(),
              "mesh_propagation::propagate: got CUDA values but this build of sfgs has no CUDA backend");
  at::NoGradGuard no_grad;
  const at::Tensor v = values.detach().contiguous();
  return v.scalar_type() == at::kDouble ? propagate_as<double>(v, plan, smoothing_passes)
                                        : propagate_as<float>(v, plan, smoothing_passes);
}

}  // namespace sfgs::mesh_propagation
