#pragma once
// Polygon meshes of the procedural body's cage: faces of any size with a UV chart each, undirected edges, outward
// orientation and the vertex map of the left/right mirror symmetry.
#include <cstdint>
#include <utility>
#include <vector>

#include "body/procedural/vec3.h"

namespace sfgs::body::procedural {

struct PolyMesh {
  std::vector<std::vector<int64_t>> faces;
  std::vector<int64_t> charts;  // per face: the UV chart it belongs to
  int64_t vertex_count = 0;
};

using Edge = std::pair<int64_t, int64_t>;
inline Edge undirected(int64_t a, int64_t b) { return a < b ? Edge{a, b} : Edge{b, a}; }

// Gives every face of each connected component the same orientation, outward (positive enclosed volume).
void orient_outward(PolyMesh& mesh, const std::vector<Vec3>& positions);

// The vertex at the mirror image of each vertex; the builder makes mirrored positions exact negations of x.
std::vector<int64_t> mirror_by_position(const std::vector<Vec3>& positions);

}  // namespace sfgs::body::procedural
