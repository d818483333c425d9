// The mesh propagation: its plan (a breadth-first front on the host), validation at the boundary, the backend by
// device, and its dispatcher registration (ops/registration.h).
#include "ops/mesh_propagation/mesh_propagation.h"

#include <algorithm>
#include <limits>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/mesh_propagation/backend.h"
#include "ops/registration.h"

namespace sfgs::mesh_propagation {
namespace {

// The ring of a point that no front reaches (its part of the mesh holds no trusted point).
constexpr int32_t kUnreached = std::numeric_limits<int32_t>::max();

// The plan's parts as the op takes them (its schema's order after the values).
struct PlanTensors {
  const at::Tensor &trust, &neighbours, &counts, &ring_points, &ring_sources, &ring_source_counts, &free_points;
};

// Shapes, dtypes and devices (`on_meta`: a Meta kernel's check, which takes meta tensors); the rings' bounds.
void check_arguments(const at::Tensor& values, const PlanTensors& p, at::IntArrayRef ring_offsets,
                     int64_t smoothing_passes, bool on_meta = false) {
  TORCH_CHECK(values.defined() && values.dim() == 2 && values.size(1) >= 1 &&
                  (values.scalar_type() == at::kFloat || values.scalar_type() == at::kDouble),
              "propagate_on_mesh: values must be a float32 or float64 (N, C) tensor, got ", describe(values));
  TORCH_CHECK(values.is_cpu() || values.is_cuda() || (on_meta && values.is_meta()),
              "propagate_on_mesh: values must be on the CPU or a CUDA device, got ", values.device());
  if (values.is_cuda()) TORCH_CHECK(ops::kBuiltWithCuda, "propagate_on_mesh: this build has no CUDA backend");
  const int64_t n = values.size(0);
  TORCH_CHECK(n < std::numeric_limits<int32_t>::max(), "propagate_on_mesh: at most 2^31 - 2 points, got ", n);
  TORCH_CHECK(p.trust.defined() && p.trust.sizes() == at::IntArrayRef({n}) &&
                  p.trust.scalar_type() == values.scalar_type() && p.trust.device() == values.device(),
              "propagate_on_mesh: trust must be a ", values.scalar_type(), " (", n, ") tensor on ", values.device(),
              ", got ", describe(p.trust));
  const auto check_index = [&](const at::Tensor& t, const char* name, at::IntArrayRef shape) {
    check_tensor(t, std::string("propagate_on_mesh: ") + name, shape, at::kInt, values.device());
  };
  TORCH_CHECK(p.neighbours.defined() && p.neighbours.dim() == 2, "propagate_on_mesh: neighbours must be (N, K), got ",
              describe(p.neighbours));
  const int64_t k = p.neighbours.size(1);
  check_index(p.neighbours, "neighbours", {n, k});
  check_index(p.counts, "counts", {n});
  TORCH_CHECK(p.ring_points.defined() && p.ring_points.dim() == 1, "propagate_on_mesh: ring_points must be (M), got ",
              describe(p.ring_points));
  const int64_t m = p.ring_points.size(0);
  check_index(p.ring_points, "ring_points", {m});
  check_index(p.ring_sources, "ring_sources", {m, k});
  check_index(p.ring_source_counts, "ring_source_counts", {m});
  TORCH_CHECK(p.free_points.defined() && p.free_points.dim() == 1, "propagate_on_mesh: free_points must be (F), got ",
              describe(p.free_points));
  check_index(p.free_points, "free_points", {p.free_points.size(0)});
  TORCH_CHECK(!ring_offsets.empty() && ring_offsets.front() == 0 && ring_offsets.back() == m,
              "propagate_on_mesh: ring_offsets must run from 0 to the ", m, " ring points, got ", ring_offsets);
  for (size_t r = 1; r < ring_offsets.size(); ++r)
    TORCH_CHECK(ring_offsets[r] >= ring_offsets[r - 1], "propagate_on_mesh: ring_offsets must not fall, got ",
                ring_offsets);
  TORCH_CHECK(smoothing_passes >= 0, "propagate_on_mesh: smoothing passes must be >= 0, got ", smoothing_passes);
}

// The CPU op reads the plan's indices where they lie and refuses one plan() could not have made (the CUDA kernels
// give such rows NaN instead: mesh_propagation_math.h).
void check_indices_on_host(const PlanTensors& p, int64_t n) {
  const int64_t k = p.neighbours.size(1);
  TORCH_CHECK(values_within(p.counts, 0, k + 1), "propagate_on_mesh: counts must lie in [0, ", k, "]");
  TORCH_CHECK(values_within(p.ring_source_counts, 0, k + 1), "propagate_on_mesh: ring_source_counts must lie in [0, ",
              k, "]");
  const at::Tensor slot = at::arange(k, p.neighbours.options()).unsqueeze(0);
  TORCH_CHECK(values_within(p.neighbours.masked_select(slot < p.counts.unsqueeze(1)), 0, n),
              "propagate_on_mesh: a neighbour lies outside [0, ", n, ")");
  TORCH_CHECK(values_within(p.ring_sources.masked_select(slot < p.ring_source_counts.unsqueeze(1)), 0, n),
              "propagate_on_mesh: a ring source lies outside [0, ", n, ")");
  TORCH_CHECK(values_within(p.ring_points, 0, n) && values_within(p.free_points, 0, n),
              "propagate_on_mesh: a ring or free point lies outside [0, ", n, ")");
}

template <typename T>
at::Tensor propagate_as(const at::Tensor& values, const PlanTensors& p, const std::vector<int64_t>& ring_offsets,
                        int64_t passes) {
  const at::Tensor filled = values.clone(), scratch = at::empty_like(values), out = at::empty_like(values);
  std::vector<at::Tensor> kept;  // what the arrays point into, alive until the kernels are queued
  const auto ints = [&kept](const at::Tensor& t) {
    kept.push_back(t.contiguous());
    return kept.back().data_ptr<int32_t>();
  };
  PropagationArrays<T> a;
  a.neighbours = ints(p.neighbours);
  a.counts = ints(p.counts);
  a.ring_points = ints(p.ring_points);
  a.ring_sources = ints(p.ring_sources);
  a.ring_source_counts = ints(p.ring_source_counts);
  a.free_points = ints(p.free_points);
  a.point_count = values.size(0);
  a.free_count = p.free_points.size(0);
  a.slots = int(p.neighbours.size(1));
  a.channels = int(values.size(1));
  a.values = values.data_ptr<T>();
  kept.push_back(p.trust.contiguous());
  a.trust = kept.back().data_ptr<T>();
  a.filled = filled.data_ptr<T>();
  a.scratch = scratch.data_ptr<T>();
  a.out = out.data_ptr<T>();
#if defined(SFGS_WITH_CUDA)
  if (values.is_cuda()) {
    cuda::propagate(a, ring_offsets, passes, values.device());
    return out;
  }
#endif
  cpu::propagate(a, ring_offsets, passes);
  return out;
}

// ---- the dispatcher op (ops/registration.h): no gradient, so its Autograd kernel refuses one ----

constexpr const char* kPropagationSchema =
    "propagate_on_mesh(Tensor values, Tensor trust, Tensor neighbours, Tensor counts, Tensor ring_points, "
    "Tensor ring_sources, Tensor ring_source_counts, Tensor free_points, int[] ring_offsets, int smoothing_passes) "
    "-> Tensor";
using PropagationSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                        const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                        at::IntArrayRef, int64_t);
#define SFGS_PROPAGATION_PARAMETERS                                                                          \
  const at::Tensor &values, const at::Tensor &trust, const at::Tensor &neighbours, const at::Tensor &counts, \
      const at::Tensor &ring_points, const at::Tensor &ring_sources, const at::Tensor &ring_source_counts,   \
      const at::Tensor &free_points, at::IntArrayRef ring_offsets, int64_t smoothing_passes
#define SFGS_PROPAGATION_PLAN \
  PlanTensors { trust, neighbours, counts, ring_points, ring_sources, ring_source_counts, free_points }

const c10::TypedOperatorHandle<PropagationSignature>& propagation_op() {
  static const auto handle = ops::find_op<PropagationSignature>("sfgs::propagate_on_mesh");
  return handle;
}

at::Tensor propagation_kernel(SFGS_PROPAGATION_PARAMETERS) {
  const PlanTensors plan = SFGS_PROPAGATION_PLAN;
  check_arguments(values, plan, ring_offsets, smoothing_passes);
  if (values.is_cpu()) check_indices_on_host(plan, values.size(0));
  const at::Tensor v = values.contiguous();
  return v.scalar_type() == at::kDouble ? propagate_as<double>(v, plan, ring_offsets.vec(), smoothing_passes)
                                        : propagate_as<float>(v, plan, ring_offsets.vec(), smoothing_passes);
}

at::Tensor propagation_meta(SFGS_PROPAGATION_PARAMETERS) {
  check_arguments(values, SFGS_PROPAGATION_PLAN, ring_offsets, smoothing_passes, /*on_meta=*/true);
  return at::empty(values.sizes(), values.options());
}

at::Tensor propagation_autograd(SFGS_PROPAGATION_PARAMETERS) {
  TORCH_CHECK(!(at::GradMode::is_enabled() && (values.requires_grad() || trust.requires_grad())),
              "propagate_on_mesh: has no gradient; detach the values (or run under torch::NoGradGuard)");
  const at::AutoDispatchBelowADInplaceOrView below_autograd;
  return propagation_op().call(values, trust, neighbours, counts, ring_points, ring_sources, ring_source_counts,
                               free_points, ring_offsets, smoothing_passes);
}

#undef SFGS_PROPAGATION_PLAN
#undef SFGS_PROPAGATION_PARAMETERS

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
  return propagation_op().call(values.detach(), plan.trust, plan.neighbours, plan.counts, plan.ring_points,
                               plan.ring_sources, plan.ring_source_counts, plan.free_points, plan.ring_offsets,
                               smoothing_passes);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) { m.def(kPropagationSchema); }
TORCH_LIBRARY_IMPL(sfgs, CPU, m) { m.impl("propagate_on_mesh", TORCH_FN(propagation_kernel)); }
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) { m.impl("propagate_on_mesh", TORCH_FN(propagation_kernel)); }
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) { m.impl("propagate_on_mesh", TORCH_FN(propagation_meta)); }
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("propagate_on_mesh", TORCH_FN(propagation_autograd)); }

}  // namespace sfgs::mesh_propagation
