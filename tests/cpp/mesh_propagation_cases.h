#pragma once
// The mesh propagation's test cases, shared by the CPU tests and the CUDA parity tests: a body mesh with a
// disconnected part, its trust, and the propagation written as its definition reads (the front advances one ring a
// pass while any point is reached, a host read a pass, then the smoothing passes).
#include <ATen/ATen.h>

#include "body/mesh.h"
#include "test_avatar_utils.h"

namespace sfgs::testing {

struct PropagationCase {
  body::VertexNeighbours neighbours;
  at::Tensor trust;  // (N) float64
};

// The procedural body's mesh plus a separate strip of 5 x 2 points that no trusted point reaches; its front trusted
// (z > 0 at rest), the rest at random trust below 1/2, a few points of the back half trusted.
inline PropagationCase body_with_detached_strip() {
  const body::SmplxModelData& model = procedural_avatar_body().smplx;
  const int64_t body_points = model.v_template.size(0), n = body_points + 10;
  std::vector<int64_t> strip;
  for (int64_t i = 0; i < 4; ++i) {
    const int64_t a = body_points + 2 * i, b = a + 1, c = a + 2, d = a + 3;
    strip.insert(strip.end(), {a, c, b, b, c, d});
  }
  const at::Tensor faces = at::cat({model.faces.to(at::kLong), at::tensor(strip, at::kLong).view({-1, 3})});
  PropagationCase out;
  out.neighbours = body::vertex_neighbours(faces, n);
  const at::Tensor front = at::cat({model.v_template.select(1, 2).to(at::kDouble) > 0, at::zeros({10}, at::kBool)});
  at::Generator g = at::detail::createCPUGenerator(5);
  out.trust = at::where(front, at::ones({n}, at::kDouble), at::rand({n}, g, at::TensorOptions(at::kDouble)) * 0.5);
  return out;
}

inline at::Tensor propagation_by_definition(const at::Tensor& values, const at::Tensor& trust,
                                            const body::VertexNeighbours& neighbours, int64_t passes) {
  const int64_t n = values.size(0), k = neighbours.indices.size(1), c = values.size(1);
  const at::Tensor known = trust >= 1.0;
  if (!known.any().item<bool>()) return values;
  const at::Tensor indices = neighbours.indices.reshape({-1});
  const at::Tensor valid = (at::arange(k).unsqueeze(0) < neighbours.counts.unsqueeze(1)).to(values.scalar_type());
  const auto around = [&](const at::Tensor& x) { return x.index_select(0, indices).view({n, k, c}); };
  at::Tensor filled = known.to(values.scalar_type());
  at::Tensor x = values * filled.unsqueeze(1);
  for (;;) {
    const at::Tensor filled_neighbours = filled.index_select(0, indices).view({n, k}) * valid;
    const at::Tensor count = filled_neighbours.sum(1);
    const at::Tensor reached = (filled == 0) & (count > 0);
    if (!reached.any().item<bool>()) break;
    const at::Tensor mean = (around(x) * filled_neighbours.unsqueeze(2)).sum(1) / count.clamp_min(1).unsqueeze(1);
    x = at::where(reached.unsqueeze(1), mean, x);
    filled = filled + reached.to(filled.scalar_type());
  }
  x = at::where((filled > 0).unsqueeze(1), x, values);
  const at::Tensor divisor = neighbours.counts.clamp_min(1).to(values.scalar_type()).unsqueeze(1);
  for (int64_t pass = 0; pass < passes; ++pass)
    x = at::where(known.unsqueeze(1), x, (around(x) * valid.unsqueeze(2)).sum(1) / divisor);
  const at::Tensor t = trust.unsqueeze(1).to(values.scalar_type());
  return t * values + (1 - t) * x;
}

}  // namespace sfgs::testing
