#include "body/procedural/catmull_clark.h"

#include <algorithm>
#include <map>
#include <stdexcept>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/skeleton.h"

namespace sfgs::body::procedural {

at::Tensor Stencil::apply(const at::Tensor& coarse) const {
  const at::Tensor r = at::tensor(rows, at::kLong), c = at::tensor(cols, at::kLong);
  const at::Tensor w = at::tensor(values, at::kDouble).unsqueeze(1);
  return at::zeros({fine_count, coarse.size(1)}, coarse.options()).index_add_(0, r, coarse.index_select(0, c) * w);
}

namespace {

// Edges of a coarse mesh numbered in order of first appearance, with the faces and vertices around them.
struct Adjacency {
  std::map<Edge, int64_t> edge_index;
  std::vector<Edge> edges;
  std::vector<std::vector<int64_t>> edge_faces, vertex_faces, vertex_edges;
};

Adjacency adjacency(const PolyMesh& coarse) {
  Adjacency a;
  a.vertex_faces.resize(coarse.vertex_count);
  a.vertex_edges.resize(coarse.vertex_count);
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    const auto& face = coarse.faces[f];
    for (size_t i = 0; i < face.size(); ++i) {
      const Edge e = undirected(face[i], face[(i + 1) % face.size()]);
      auto [it, inserted] = a.edge_index.emplace(e, static_cast<int64_t>(a.edges.size()));
      if (inserted) {
        a.edges.push_back(e);
        a.edge_faces.emplace_back();
        a.vertex_edges[e.first].push_back(it->second);
        a.vertex_edges[e.second].push_back(it->second);
      }
      a.edge_faces[it->second].push_back(static_cast<int64_t>(f));
      a.vertex_faces[face[i]].push_back(static_cast<int64_t>(f));
    }
  }
  for (const auto& faces : a.edge_faces) {
    if (faces.size() != 2) throw std::logic_error("procedural body: the cage is not a closed 2-manifold");
  }
  return a;
}

void add_row(Stencil& stencil, int64_t row, const std::map<int64_t, double>& terms) {
  for (const auto& [col, value] : terms) {
    stencil.rows.push_back(row);
    stencil.cols.push_back(col);
    stencil.values.push_back(value);
  }
}

// The fine vertices as combinations of coarse ones: vertex points, edge points, face points.
Stencil subdivision_stencil(const PolyMesh& coarse, const Adjacency& a) {
  const int64_t v = coarse.vertex_count;
  const int64_t e_count = static_cast<int64_t>(a.edges.size());
  Stencil stencil;
  stencil.fine_count = v + e_count + static_cast<int64_t>(coarse.faces.size());
  for (int64_t i = 0; i < v; ++i) {
    // (Q + 2R + (n - 3) S) / n: Q averages the adjacent face points, R the incident edge midpoints.
    const double n = static_cast<double>(a.vertex_edges[i].size());
    std::map<int64_t, double> terms;
    for (int64_t f : a.vertex_faces[i]) {
      const auto& face = coarse.faces[f];
      for (int64_t u : face) terms[u] += 1.0 / (n * n * static_cast<double>(face.size()));
    }
    for (int64_t e : a.vertex_edges[i]) {
      terms[a.edges[e].first] += 1.0 / (n * n);
      terms[a.edges[e].second] += 1.0 / (n * n);
    }
    terms[i] += (n - 3.0) / n;
    add_row(stencil, i, terms);
  }
  for (int64_t e = 0; e < e_count; ++e) {
    std::map<int64_t, double> terms;
    terms[a.edges[e].first] += 0.25;
    terms[a.edges[e].second] += 0.25;
    for (int64_t f : a.edge_faces[e]) {
      const auto& face = coarse.faces[f];
      for (int64_t u : face) terms[u] += 0.25 / static_cast<double>(face.size());
    }
    add_row(stencil, v + e, terms);
  }
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    std::map<int64_t, double> terms;
    for (int64_t u : coarse.faces[f]) terms[u] += 1.0 / static_cast<double>(coarse.faces[f].size());
    add_row(stencil, v + e_count + static_cast<int64_t>(f), terms);
  }
  return stencil;
}

PolyMesh fine_quads(const PolyMesh& coarse, const Adjacency& a) {
  const int64_t v = coarse.vertex_count;
  const int64_t e_count = static_cast<int64_t>(a.edges.size());
  PolyMesh fine;
  fine.vertex_count = v + e_count + static_cast<int64_t>(coarse.faces.size());
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    const auto& face = coarse.faces[f];
    const int64_t k = static_cast<int64_t>(face.size());
    const int64_t face_point = v + e_count + static_cast<int64_t>(f);
    for (int64_t i = 0; i < k; ++i) {
      const int64_t next = v + a.edge_index.at(undirected(face[i], face[(i + 1) % k]));
      const int64_t previous = v + a.edge_index.at(undirected(face[(i + k - 1) % k], face[i]));
      fine.faces.push_back({face[i], next, face_point, previous});
      fine.charts.push_back(coarse.charts[f]);
    }
  }
  return fine;
}

// Each fine vertex's mirror image: a vertex point maps as its vertex, an edge point to the edge between the mirrored
// ends, a face point to the face with the mirrored vertex set.
std::vector<int64_t> fine_mirror(const PolyMesh& coarse, const Adjacency& a, const std::vector<int64_t>& mirror) {
  const int64_t v = coarse.vertex_count;
  const int64_t e_count = static_cast<int64_t>(a.edges.size());
  std::map<std::vector<int64_t>, int64_t> face_by_vertices;
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    std::vector<int64_t> key = coarse.faces[f];
    std::sort(key.begin(), key.end());
    face_by_vertices[key] = static_cast<int64_t>(f);
  }
  std::vector<int64_t> fine(v + e_count + static_cast<int64_t>(coarse.faces.size()));
  for (int64_t i = 0; i < v; ++i) fine[i] = mirror[i];
  for (int64_t e = 0; e < e_count; ++e)
    fine[v + e] = v + a.edge_index.at(undirected(mirror[a.edges[e].first], mirror[a.edges[e].second]));
  for (size_t f = 0; f < coarse.faces.size(); ++f) {
    std::vector<int64_t> key;
    for (int64_t u : coarse.faces[f]) key.push_back(mirror[u]);
    std::sort(key.begin(), key.end());
    fine[v + e_count + static_cast<int64_t>(f)] = v + e_count + face_by_vertices.at(key);
  }
  return fine;
}

at::Tensor positions_tensor(const std::vector<Vec3>& positions) {
  at::Tensor t = at::empty({static_cast<int64_t>(positions.size()), 3}, at::kDouble);
  auto a = t.accessor<double, 2>();
  for (size_t i = 0; i < positions.size(); ++i)
    for (int k = 0; k < 3; ++k) a[i][k] = positions[i][k];
  return t;
}

at::Tensor weights_tensor(const std::vector<JointWeights>& weights) {
  at::Tensor t = at::zeros({static_cast<int64_t>(weights.size()), kSmplxJointCount}, at::kDouble);
  auto a = t.accessor<double, 2>();
  for (size_t i = 0; i < weights.size(); ++i)
    for (const auto& [j, w] : weights[i]) a[i][j] += w;
  return t / t.sum(1, /*keepdim=*/true);
}

}  // namespace

Subdivided catmull_clark(const PolyMesh& coarse, const std::vector<int64_t>& mirror) {
  const Adjacency a = adjacency(coarse);
  Subdivided out;
  out.stencil = subdivision_stencil(coarse, a);
  out.mesh = fine_quads(coarse, a);
  out.mirror = fine_mirror(coarse, a, mirror);
  return out;
}

Smoothed smooth(const Cage& cage) {
  PolyMesh mesh = cage.mesh();
  mesh.vertex_count = static_cast<int64_t>(cage.positions().size());
  orient_outward(mesh, cage.positions());
  const Subdivided first = catmull_clark(mesh, mirror_by_position(cage.positions()));
  const Subdivided second = catmull_clark(first.mesh, first.mirror);
  Smoothed out;
  out.positions = second.stencil.apply(first.stencil.apply(positions_tensor(cage.positions())));
  const at::Tensor weights = second.stencil.apply(first.stencil.apply(weights_tensor(cage.weights())));
  out.weights = weights / weights.sum(1, /*keepdim=*/true);
  out.quads = second.mesh;
  out.mirror = second.mirror;
  return out;
}

}  // namespace sfgs::body::procedural
