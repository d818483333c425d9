// The fused vertex normals' kernel (body_kernels.h): per vertex, the sum over its faces of (v1 - v0) x (v2 - v0)
// (twice the area times the unit normal) in the fixed order of VertexFaces, then normalised, or zero where the sum is
// shorter than min_length. A gather rather than a scatter of atomic adds: the same bits on every run.
#include "cuda/body_kernels.h"
#include "cuda/launch_geometry.cuh"

namespace sfgs::body::cuda_kernels {
namespace {

constexpr int kThreads = 256;

__global__ void vertex_normals_kernel(const VertexNormalArrays a) {
  const int64_t v = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (v >= a.vertex_count) return;
  float sum[3] = {0.f, 0.f, 0.f};
  for (int32_t k = a.face_offsets[v]; k < a.face_offsets[v + 1]; ++k) {
    const int64_t* corners = a.faces + int64_t(a.vertex_faces[k]) * 3;
    const int64_t i0 = corners[0], i1 = corners[1], i2 = corners[2];
    const auto outside = [&](int64_t i) { return i < 0 || i >= a.vertex_count; };
    if (outside(i0) || outside(i1) || outside(i2)) continue;  // no read outside the arrays
    float p0[3], e1[3], e2[3];
    for (int c = 0; c < 3; ++c) p0[c] = a.vertices[i0 * 3 + c];
    for (int c = 0; c < 3; ++c) {
      e1[c] = a.vertices[i1 * 3 + c] - p0[c];
      e2[c] = a.vertices[i2 * 3 + c] - p0[c];
    }
    sum[0] += e1[1] * e2[2] - e1[2] * e2[1];
    sum[1] += e1[2] * e2[0] - e1[0] * e2[2];
    sum[2] += e1[0] * e2[1] - e1[1] * e2[0];
  }
  const float length = sqrtf(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
  const float scale = length > a.min_length ? 1.f / length : 0.f;
  for (int c = 0; c < 3; ++c) a.normals[v * 3 + c] = sum[c] * scale;
}

}  // namespace

void vertex_normals_forward(const VertexNormalArrays& a, cudaStream_t stream) {
  if (a.vertex_count == 0) return;
  vertex_normals_kernel<<<unsigned((a.vertex_count + kThreads - 1) / kThreads), kThreads, 0, stream>>>(a);
  cuda_launch::check_launch("vertex normals", "vertex_normals_kernel");
}

}  // namespace sfgs::body::cuda_kernels
