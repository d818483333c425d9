#pragma once
// Catmull-Clark subdivision of the procedural body's cage, kept as a linear stencil so positions and skinning
// weights are smoothed by the same operator, with the mirror map carried along exactly.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

#include "body/procedural/cage.h"
#include "body/procedural/poly_mesh.h"

namespace sfgs::body::procedural {

// Fine vertex rows[k] receives values[k] times coarse vertex cols[k]: subdivision is linear in vertex data.
struct Stencil {
  std::vector<int64_t> rows, cols;
  std::vector<double> values;
  int64_t fine_count = 0;

  at::Tensor apply(const at::Tensor& coarse) const;
};

struct Subdivided {
  PolyMesh mesh;
  Stencil stencil;
  std::vector<int64_t> mirror;
};

// One Catmull-Clark step on a closed polygon mesh. Fine vertices: vertex points (old indices), then edge points,
// then face points. Face (v0 .. vk-1) becomes the quads (v_i, e(v_i v_i+1), f, e(v_i-1 v_i)), which keep its
// orientation and chart. The mirror map follows combinatorially, so symmetry survives exactly.
Subdivided catmull_clark(const PolyMesh& coarse, const std::vector<int64_t>& mirror);

// A cage smoothed by two Catmull-Clark steps: positions, weights, the quads (corner 0 a vertex point, corner 2 a
// face point) with their charts, and the mirror map.
struct Smoothed {
  at::Tensor positions, weights;
  PolyMesh quads;
  std::vector<int64_t> mirror;
};

// Orients the cage outward and smooths it; weights are renormalised to sum to 1 per vertex.
Smoothed smooth(const Cage& cage);

}  // namespace sfgs::body::procedural
