#include "body/mesh.h"

#include <cstdint>
#include <limits>
#include <tuple>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/body_backend.h"
#include "body/tensor_checks.h"
#include "body/constants.h"

namespace sfgs::body {

at::Tensor checked_faces(const at::Tensor& faces, int64_t num_vertices, const std::string& what) {
  TORCH_CHECK(faces.defined() && faces.dim() == 2 && faces.size(1) == 3 &&
                  at::isIntegralType(faces.scalar_type(), /*includeBool=*/false),
              what, " must be an integer (F, 3) tensor, got ", describe(faces));
  at::Tensor result = faces.to(at::kCPU, at::kLong).contiguous();
  if (result.numel() > 0) {
    const int64_t low = result.min().item<int64_t>(), high = result.max().item<int64_t>();
    TORCH_CHECK(low >= 0 && high < num_vertices, what, " index vertices ", low, "..", high, ", but there are ",
                num_vertices, " vertices");
  }
  return result;
}

MeshEdges mesh_edges(const at::Tensor& faces, int64_t num_vertices) {
  const at::Tensor f = checked_faces(faces, num_vertices, "faces");
  const int64_t face_count = f.size(0);
  const at::Tensor v0 = f.select(1, 0), v1 = f.select(1, 1), v2 = f.select(1, 2);
  // Slot k of a face is the edge opposite corner k: (v1, v2), (v2, v0), (v0, v1).
  const at::Tensor a = at::cat({v1, v2, v0}), b = at::cat({v2, v0, v1});
  const at::Tensor key = at::minimum(a, b) * num_vertices + at::maximum(a, b);
  const auto [sorted_key, order] = key.sort();
  const auto [unique_key, sorted_inverse, counts] = at::unique_consecutive(sorted_key, /*return_inverse=*/true);
  const at::Tensor inverse = at::empty_like(sorted_inverse).scatter_(0, order, sorted_inverse);
  MeshEdges result;
  result.edges = at::stack({unique_key.div(num_vertices, "floor"), unique_key.remainder(num_vertices)}, 1);
  result.face_edges = inverse.view({3, face_count}).t().contiguous();
  return result;
}

at::Tensor append_edge_midpoints(const at::Tensor& values, const at::Tensor& edges, int64_t dim) {
  const at::Tensor e = edges.to(values.device());
  const at::Tensor first = values.index_select(dim, e.select(1, 0));
  const at::Tensor second = values.index_select(dim, e.select(1, 1));
  return at::cat({values, 0.5 * (first + second)}, dim);
}

MidpointSubdivision::MidpointSubdivision(const at::Tensor& faces, int64_t num_vertices) : num_vertices_(num_vertices) {
  const at::Tensor f = checked_faces(faces, num_vertices, "faces");
  const MeshEdges topology = mesh_edges(f, num_vertices);
  edges_ = topology.edges;
  const at::Tensor e = topology.face_edges + num_vertices;
  const at::Tensor v0 = f.select(1, 0), v1 = f.select(1, 1), v2 = f.select(1, 2);
  const at::Tensor e0 = e.select(1, 0), e1 = e.select(1, 1), e2 = e.select(1, 2);
  fine_faces_ = at::cat(
      {at::stack({v0, e2, e1}, 1), at::stack({v1, e0, e2}, 1), at::stack({v2, e1, e0}, 1), at::stack({e0, e1, e2}, 1)});
}

at::Tensor MidpointSubdivision::interpolate(const at::Tensor& values, int64_t dim) const {
  TORCH_CHECK(values.defined() && values.dim() > 0,
              "MidpointSubdivision::interpolate: values must have a vertex "
              "dimension, got ",
              describe(values));
  const int64_t d = dim < 0 ? dim + values.dim() : dim;
  TORCH_CHECK(d >= 0 && d < values.dim() && values.size(d) == num_vertices_,
              "MidpointSubdivision::interpolate: values must have ", num_vertices_, " entries along dimension ", dim,
              ", got ", describe(values));
  TORCH_CHECK(at::isFloatingType(values.scalar_type()),
              "MidpointSubdivision::interpolate: values must be floating (use interpolate_labels for labels), got ",
              describe(values));
  return append_edge_midpoints(values, edges_, d);
}

at::Tensor MidpointSubdivision::interpolate_labels(const at::Tensor& labels) const {
  TORCH_CHECK(labels.defined() && labels.dim() == 1 && labels.size(0) == num_vertices_,
              "MidpointSubdivision::interpolate_labels: labels must have shape (", num_vertices_, "), got ",
              describe(labels));
  const at::Tensor e = edges_.to(labels.device());
  return at::cat({labels, at::maximum(labels.index_select(0, e.select(1, 0)), labels.index_select(0, e.select(1, 1)))});
}

std::vector<MidpointSubdivision> midpoint_subdivisions(const at::Tensor& faces, int64_t num_vertices, int64_t levels) {
  TORCH_CHECK(levels >= 0, "midpoint_subdivisions: levels must be >= 0, got ", levels);
  std::vector<MidpointSubdivision> chain;
  at::Tensor f = faces;
  int64_t v = num_vertices;
  for (int64_t level = 0; level < levels; ++level) {
    chain.emplace_back(f, v);
    f = chain.back().fine_faces();
    v = chain.back().fine_vertex_count();
  }
  return chain;
}

VertexNeighbours vertex_neighbours(const at::Tensor& faces, int64_t num_vertices, int64_t max_neighbours) {
  TORCH_CHECK(max_neighbours == -1 || max_neighbours > 0,
              "vertex_neighbours: max_neighbours must be -1 (all) or > 0, got ", max_neighbours);
  const at::Tensor edges = mesh_edges(faces, num_vertices).edges;
  const at::Tensor source = at::cat({edges.select(1, 0), edges.select(1, 1)});
  const at::Tensor target = at::cat({edges.select(1, 1), edges.select(1, 0)});
  const at::Tensor order = std::get<1>((source * num_vertices + target).sort());
  const at::Tensor s = source.index_select(0, order), t = target.index_select(0, order);
  const at::Tensor valence = at::bincount(s, {}, num_vertices);
  const at::Tensor first_slot = valence.cumsum(0) - valence;
  const at::Tensor slot = at::arange(s.size(0), s.options()) - first_slot.index_select(0, s);
  const int64_t widest = num_vertices > 0 && s.size(0) > 0 ? valence.max().item<int64_t>() : 0;
  const int64_t k = max_neighbours < 0 ? widest : std::min(widest, max_neighbours);
  VertexNeighbours result;
  result.indices = at::arange(num_vertices, s.options()).unsqueeze(1).repeat({1, std::max<int64_t>(k, 1)});
  const at::Tensor kept = slot < k;
  result.indices.view(-1).index_copy_(0, (s * result.indices.size(1) + slot).masked_select(kept),
                                      t.masked_select(kept));
  result.counts = valence.clamp_max(k);
  return result;
}

at::Tensor uniform_laplacian(const VertexNeighbours& neighbours, const at::Tensor& values) {
  const int64_t v = neighbours.counts.size(0);
  TORCH_CHECK(values.defined() && (values.dim() == 2 || values.dim() == 3) && values.size(-2) == v &&
                  at::isFloatingType(values.scalar_type()),
              "uniform_laplacian: values must be floating with shape (", v, ", C) or (B, ", v, ", C), got ",
              describe(values));
  const at::Tensor indices = neighbours.indices.to(values.device());
  const at::Tensor counts = neighbours.counts.to(values.device());
  const int64_t k = indices.size(1);
  const at::Tensor valid = (at::arange(k, indices.options()).unsqueeze(0) < counts.unsqueeze(1))
                               .to(values.scalar_type())
                               .unsqueeze(-1);  // (V, K, 1)
  auto shape = values.sizes().vec();
  shape.insert(shape.end() - 1, k);  // (..., V, K, C)
  const at::Tensor gathered = values.index_select(values.dim() - 2, indices.flatten()).view(shape);
  const at::Tensor mean = (gathered * valid).sum(-2) / counts.clamp_min(1).to(values.scalar_type()).unsqueeze(-1);
  const at::Tensor isolated = (counts == 0).unsqueeze(-1);
  return at::where(isolated, at::zeros_like(values), values - mean);
}

VertexFaces vertex_faces(const at::Tensor& faces, int64_t num_vertices) {
  TORCH_CHECK(faces.defined() && faces.dim() == 2 && faces.size(1) == 3 && faces.scalar_type() == at::kLong,
              "vertex_faces: faces must be an int64 (F, 3) tensor, got ", describe(faces));
  TORCH_CHECK(num_vertices >= 0 && num_vertices < std::numeric_limits<int32_t>::max() &&
                  3 * faces.size(0) < std::numeric_limits<int32_t>::max(),
              "vertex_faces: int32 indices hold fewer than 2^31 vertices and corners, got ", num_vertices,
              " vertices and ", faces.size(0), " faces");
  const int64_t f = faces.size(0);
  const at::Tensor inside = ((faces >= 0) & (faces < num_vertices)).all(1).repeat({3});
  // Corner-major (all first corners, then all second, then all third): a stable sort by vertex then gives each
  // vertex its faces in the reference's order of summation.
  const at::Tensor corners = faces.t().reshape({-1});
  const at::Tensor keys = at::where(inside, corners, at::full_like(corners, num_vertices));
  const auto [sorted, order] = at::sort(keys, /*stable=*/true, /*dim=*/0, /*descending=*/false);
  VertexFaces result;
  result.offsets = at::searchsorted(sorted, at::arange(num_vertices + 1, keys.options())).to(at::kInt);
  result.face_indices = f > 0 ? order.remainder(f).to(at::kInt) : order.to(at::kInt);
  return result;
}

at::Tensor vertex_normals(const at::Tensor& vertices, const at::Tensor& faces, const VertexFaces& around) {
  TORCH_CHECK(vertices.defined() && vertices.dim() == 2 && vertices.size(1) == 3,
              "vertex_normals: vertices must have shape (V, 3), got ", describe(vertices));
  TORCH_CHECK(faces.defined() && faces.dim() == 2 && faces.size(1) == 3 && faces.scalar_type() == at::kLong &&
                  faces.device() == vertices.device(),
              "vertex_normals: faces must be an int64 (F, 3) tensor on ", vertices.device(), ", got ", describe(faces));
  const bool fused =
      vertices.is_cuda() && vertices.scalar_type() == at::kFloat && !vertices.requires_grad() && cuda::available();
  if (!fused) return vertex_normals_reference(vertices, faces);
  const int64_t v = vertices.size(0);
  const VertexFaces made = around.offsets.defined() ? VertexFaces() : vertex_faces(faces, v);
  const VertexFaces& used = around.offsets.defined() ? around : made;
  TORCH_CHECK(used.offsets.dim() == 1 && used.offsets.size(0) == v + 1 && used.offsets.scalar_type() == at::kInt &&
                  used.offsets.device() == vertices.device() && used.face_indices.dim() == 1 &&
                  used.face_indices.size(0) == 3 * faces.size(0) && used.face_indices.scalar_type() == at::kInt &&
                  used.face_indices.device() == vertices.device(),
              "vertex_normals: the faces around the vertices must be vertex_faces of these ", faces.size(0),
              " faces and ", v, " vertices on ", vertices.device(), ", got offsets ", describe(used.offsets),
              " and face indices ", describe(used.face_indices));
  const at::Tensor points = vertices.contiguous(), f = faces.contiguous();
  const at::Tensor offsets = used.offsets.contiguous(), face_indices = used.face_indices.contiguous();
  at::Tensor normals = at::empty_like(points);
  VertexNormalArrays arrays{};
  arrays.vertices = points.data_ptr<float>();
  arrays.faces = f.data_ptr<int64_t>();
  arrays.face_offsets = offsets.data_ptr<int32_t>();
  arrays.vertex_faces = face_indices.data_ptr<int32_t>();
  arrays.vertex_count = v;
  arrays.min_length = static_cast<float>(kMinNormalLength);
  arrays.normals = normals.data_ptr<float>();
  cuda::vertex_normals(arrays, points.device());
  return normals;
}

at::Tensor vertex_normals_reference(const at::Tensor& vertices, const at::Tensor& faces) {
  const at::Tensor v0 = vertices.index_select(0, faces.select(1, 0));
  const at::Tensor v1 = vertices.index_select(0, faces.select(1, 1));
  const at::Tensor v2 = vertices.index_select(0, faces.select(1, 2));
  const at::Tensor face_normals = at::linalg_cross(v1 - v0, v2 - v0, -1);  // length: twice the area
  at::Tensor sums = at::zeros_like(vertices);
  for (int64_t corner = 0; corner < 3; ++corner) sums.index_add_(0, faces.select(1, corner), face_normals);
  const at::Tensor length = sums.pow(2).sum(1, /*keepdim=*/true).sqrt();
  return at::where(length > kMinNormalLength, sums / length.clamp_min(kMinNormalLength), at::zeros_like(sums));
}

}  // namespace sfgs::body
