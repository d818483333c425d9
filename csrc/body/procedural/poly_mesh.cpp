#include "body/procedural/poly_mesh.h"

#include <algorithm>
#include <map>
#include <queue>
#include <stdexcept>

namespace sfgs::body::procedural {
namespace {

bool has_directed_edge(const std::vector<int64_t>& face, int64_t a, int64_t b) {
  for (size_t i = 0; i < face.size(); ++i)
    if (face[i] == a && face[(i + 1) % face.size()] == b) return true;
  return false;
}

std::map<Edge, std::vector<int64_t>> faces_of_edges(const PolyMesh& mesh) {
  std::map<Edge, std::vector<int64_t>> faces_of_edge;
  for (size_t f = 0; f < mesh.faces.size(); ++f)
    for (size_t i = 0; i < mesh.faces[f].size(); ++i)
      faces_of_edge[undirected(mesh.faces[f][i], mesh.faces[f][(i + 1) % mesh.faces[f].size()])].push_back(
          static_cast<int64_t>(f));
  return faces_of_edge;
}

// Walks the faces connected to `seed` across shared edges, reversing each newly reached face that runs an edge in
// the same direction as its neighbour, so the component ends up consistently oriented. Returns the component.
std::vector<int64_t> orient_component(PolyMesh& mesh, const std::map<Edge, std::vector<int64_t>>& faces_of_edge,
                                      int64_t seed, std::vector<bool>& done) {
  std::vector<int64_t> component;
  std::queue<int64_t> queue;
  queue.push(seed);
  done[seed] = true;
  while (!queue.empty()) {
    const int64_t f = queue.front();
    queue.pop();
    component.push_back(f);
    const auto face = mesh.faces[f];
    for (size_t i = 0; i < face.size(); ++i) {
      const int64_t a = face[i], b = face[(i + 1) % face.size()];
      for (int64_t g : faces_of_edge.at(undirected(a, b))) {
        if (g == f) continue;
        const bool same_direction = has_directed_edge(mesh.faces[g], a, b);
        if (done[g]) {
          if (same_direction) throw std::logic_error("procedural body: the cage is not orientable");
          continue;
        }
        if (same_direction) std::reverse(mesh.faces[g].begin(), mesh.faces[g].end());
        done[g] = true;
        queue.push(g);
      }
    }
  }
  return component;
}

}  // namespace

void orient_outward(PolyMesh& mesh, const std::vector<Vec3>& positions) {
  const std::map<Edge, std::vector<int64_t>> faces_of_edge = faces_of_edges(mesh);
  std::vector<bool> done(mesh.faces.size(), false);
  for (size_t seed = 0; seed < mesh.faces.size(); ++seed) {
    if (done[seed]) continue;
    const std::vector<int64_t> component = orient_component(mesh, faces_of_edge, static_cast<int64_t>(seed), done);
    // Six times the signed volume, from a fan of triangles per face: negative means the faces point inward.
    double volume = 0;
    for (int64_t f : component) {
      const auto& face = mesh.faces[f];
      for (size_t i = 1; i + 1 < face.size(); ++i)
        volume += dot(positions[face[0]], cross(positions[face[i]], positions[face[i + 1]]));
    }
    if (volume < 0)
      for (int64_t f : component) std::reverse(mesh.faces[f].begin(), mesh.faces[f].end());
  }
}

std::vector<int64_t> mirror_by_position(const std::vector<Vec3>& positions) {
  std::map<Vec3, int64_t> index;
  for (size_t i = 0; i < positions.size(); ++i) {
    if (!index.emplace(positions[i], static_cast<int64_t>(i)).second)
      throw std::logic_error("procedural body: two cage vertices coincide");
  }
  std::vector<int64_t> mirror(positions.size());
  for (size_t i = 0; i < positions.size(); ++i) {
    const auto it = index.find(mirrored(positions[i]));
    if (it == index.end()) throw std::logic_error("procedural body: the cage is not symmetric");
    mirror[i] = it->second;
  }
  return mirror;
}

}  // namespace sfgs::body::procedural
