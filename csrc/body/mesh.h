#pragma once
// Triangle-mesh topology for the body models: unique edges in PyTorch3D's order, midpoint subdivision (the
// upsampling ExAvatar and SFGS apply twice to SMPL-X), vertex neighbourhoods and the uniform Laplacian.
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

namespace sfgs::body {

// `faces` as an (F, 3) int64 CPU tensor, after checking it is an integer (F, 3) tensor whose indices lie in
// [0, num_vertices); `what` names it in the error ("faces of 'SMPLX_NEUTRAL.npz'").
at::Tensor checked_faces(const at::Tensor& faces, int64_t num_vertices, const std::string& what);

struct MeshEdges {
  at::Tensor edges;       // (E, 2) int64: every undirected edge once as (low, high), sorted lexicographically
  at::Tensor face_edges;  // (F, 3) int64: slot k is the index of the edge opposite corner k
};
MeshEdges mesh_edges(const at::Tensor& faces, int64_t num_vertices);

// Appends, along `dim`, the mean of the two endpoint entries of every edge: fine vertex V + e is the midpoint of
// edge e. Works for any trailing shape (positions, weights, blend shapes, UVs), device and floating dtype.
at::Tensor append_edge_midpoints(const at::Tensor& values, const at::Tensor& edges, int64_t dim = 0);

// One level of midpoint subdivision, PyTorch3D SubdivideMeshes' layout: the V original vertices keep their indices
// and the E edge midpoints follow in edge order; each face (v0, v1, v2) with opposite-edge midpoints (e0, e1, e2)
// becomes (v0, e2, e1), (v1, e0, e2), (v2, e1, e0), (e0, e1, e2), written block-wise (all first corners, then all
// second corners, ...). A mesh stays closed, keeps its orientation and its Euler characteristic.
class MidpointSubdivision {
 public:
  MidpointSubdivision(const at::Tensor& faces, int64_t num_vertices);

  int64_t coarse_vertex_count() const { return num_vertices_; }
  int64_t fine_vertex_count() const { return num_vertices_ + edges_.size(0); }
  const at::Tensor& edges() const { return edges_; }
  const at::Tensor& fine_faces() const { return fine_faces_; }

  // Per-vertex values (size coarse_vertex_count along `dim`) at the fine vertices.
  at::Tensor interpolate(const at::Tensor& values, int64_t dim = 0) const;
  // Integer labels (V) at the fine vertices: a midpoint takes the larger label of its endpoints, which for
  // part labels (body = 0) is what thresholding averaged part masks at > 0 gives.
  at::Tensor interpolate_labels(const at::Tensor& labels) const;

 private:
  int64_t num_vertices_;
  at::Tensor edges_;
  at::Tensor fine_faces_;
};

// `levels` successive subdivisions; element k subdivides the mesh that element k - 1 produced.
std::vector<MidpointSubdivision> midpoint_subdivisions(const at::Tensor& faces, int64_t num_vertices, int64_t levels);

// Mesh neighbours of every vertex, at most `max_neighbours` of them (the lowest-indexed ones; -1 keeps all).
struct VertexNeighbours {
  at::Tensor indices;  // (V, K) int64, sorted per row; unused slots hold the vertex itself
  at::Tensor counts;   // (V) int64: valid slots per row
};
VertexNeighbours vertex_neighbours(const at::Tensor& faces, int64_t num_vertices, int64_t max_neighbours = -1);

// The faces around each vertex in the order the CPU reference sums them (those where it is the first corner, by
// face, then the second, then the third): vertex v's faces are face_indices[offsets[v] .. offsets[v + 1]), int32 on the
// faces' device. A face with an index outside [0, V) is left out. Made by a stable sort, no atomics.
struct VertexFaces {
  at::Tensor offsets;       // (V + 1) int32
  at::Tensor face_indices;  // (3 F) int32; entries beyond offsets[V] belong to left-out faces
};
VertexFaces vertex_faces(const at::Tensor& faces, int64_t num_vertices);

// Area-weighted unit vertex normals (V, 3) of vertices (V, 3) with faces (F, 3) int64 on the same device
// (counter-clockwise seen from outside); vertices on no face, or only on degenerate ones, get 0. For float32 CUDA
// vertices that need no gradient it is one fused kernel (csrc/cuda/vertex_normals.cu): each vertex sums its faces'
// normals in the order of `around` (vertex_faces of these very faces, made here when not given; its shapes are
// checked, its values trusted: other faces' lists give wrong normals or reads out of bounds), so the result is the
// same bits on every run (an atomic scatter's order varies, and a training step's bfloat16 LPIPS turned that noise
// into 1 % changes of the hands' gradients); a face with an index outside [0, V) is skipped rather than checked
// with a device read. Otherwise vertex_normals_reference.
at::Tensor vertex_normals(const at::Tensor& vertices, const at::Tensor& faces, const VertexFaces& around = {});
// The LibTorch composition (differentiable, any dtype and device), the fused path's reference.
at::Tensor vertex_normals_reference(const at::Tensor& vertices, const at::Tensor& faces);

// Uniform Laplacian x_i - mean of x_j over the neighbours j of i, for values (V, C) or (B, V, C) on any device;
// isolated vertices get 0. Differentiable; deterministic on every device (a gather, no atomics).
at::Tensor uniform_laplacian(const VertexNeighbours& neighbours, const at::Tensor& values);

}  // namespace sfgs::body
