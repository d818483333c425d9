#pragma once
// Values carried over a mesh from its trusted points to the rest, in one pass a ring and one a smoothing step (a CPU
// backend and CUDA kernels by device): the observation prior's propagation (model/observation_prior.h), which a
// replayed frame applies to its colours. A front from the points of trust 1 fills the others ring by ring with the
// mean of their neighbours filled before, smoothing passes relax the filled points towards the mean of all their
// neighbours (the trusted ones stay), and each point returns trust v + (1 - trust) propagated.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

#include "body/mesh.h"

namespace sfgs::mesh_propagation {

// Which points the front fills in which ring depends on the trust alone: found once (on the host), applied to any
// values after (no host read: a CUDA graph records the application).
struct Plan {
  int64_t point_count = 0;
  bool any_trusted = false;              // false: nothing to propagate from, values pass unchanged
  at::Tensor neighbours;                 // (N, K) int32
  at::Tensor counts;                     // (N) int32: valid neighbour slots
  at::Tensor ring_points;                // (M) int32: every ring's points, ring after ring
  at::Tensor ring_sources;               // (M, K) int32: a ring point's neighbours filled before its ring, first
  at::Tensor ring_source_counts;         // (M) int32: how many
  at::Tensor free_points;                // int32: the points whose trust is below 1
  at::Tensor trust;                      // (N) in the plan's dtype
  std::vector<int64_t> ring_offsets{0};  // ring r fills ring_points[ring_offsets[r] .. ring_offsets[r + 1])

  int64_t ring_count() const { return int64_t(ring_offsets.size()) - 1; }
  int64_t filled_count() const { return ring_offsets.back(); }
  int64_t widest_ring() const;
};

// The plan for trust (N) in [0, 1] (any device) over the mesh's neighbours (N points), its tensors on `device` in
// `dtype` (float32 or float64).
Plan plan(const at::Tensor& trust, const body::VertexNeighbours& neighbours, at::Device device, at::ScalarType dtype);

// values (N, C) on the plan's device in its dtype -> (N, C): propagated by the plan with `smoothing_passes` passes,
// through the dispatcher op sfgs::propagate_on_mesh (the plan's tensors and rings as its arguments). No gradient: the
// values are detached. The op's CPU kernel refuses a plan whose indices lie outside the mesh; its CUDA kernels give
// the points such an index reaches NaN and skip a target outside the mesh (mesh_propagation_math.h).
at::Tensor propagate(const at::Tensor& values, const Plan& plan, int64_t smoothing_passes);

}  // namespace sfgs::mesh_propagation
