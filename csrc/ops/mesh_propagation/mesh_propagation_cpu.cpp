// CPU backend of the mesh propagation: mesh_propagation_math.h's steps over parallel ranges of each ring, each
// smoothing pass and the blend.
#include <algorithm>
#include <cstring>
#include <utility>

#include <ATen/Parallel.h>

#include "ops/mesh_propagation/backend.h"

namespace sfgs::mesh_propagation::cpu {
namespace {

constexpr int64_t kPointsPerTask = 2048;  // at::parallel_for's grain: a task's share is worth a thread

template <typename T>
void run(const PropagationArrays<T>& a, const std::vector<int64_t>& ring_offsets, int64_t passes) {
  const int64_t values = a.point_count * a.channels;
  for (size_t r = 0; r + 1 < ring_offsets.size(); ++r)
    at::parallel_for(ring_offsets[r], ring_offsets[r + 1], kPointsPerTask, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) fill_ring_point(a, i);
    });
  // Both buffers hold the trusted rows: a pass writes the free rows of one from the other.
  std::memcpy(a.scratch, a.filled, sizeof(T) * size_t(values));
  T* from = a.filled;
  T* to = a.scratch;
  for (int64_t pass = 0; pass < passes; ++pass) {
    at::parallel_for(0, a.free_count, kPointsPerTask, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) smooth_free_point(a, i, from, to);
    });
    std::swap(from, to);
  }
  at::parallel_for(0, values, kPointsPerTask * a.channels, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) a.out[i] = blend_by_trust(a.trust[i / a.channels], a.values[i], from[i]);
  });
}

}  // namespace

void propagate(const PropagationArrays<float>& a, const std::vector<int64_t>& offsets, int64_t passes) {
  run(a, offsets, passes);
}
void propagate(const PropagationArrays<double>& a, const std::vector<int64_t>& offsets, int64_t passes) {
  run(a, offsets, passes);
}

}  // namespace sfgs::mesh_propagation::cpu
