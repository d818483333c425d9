// The fused vertex normals' kernels (body_kernels.h): the sum over a vertex's faces of (v1 - v0) x (v2 - v0) (twice
// the area times the unit normal), then normalised, or zero where the sum is shorter than min_length.
#include <stdexcept>
#include <string>

#include "cuda/body_kernels.h"

namespace sfgs::body::cuda_kernels {
namespace {

constexpr int kThreads = 256;

__global__ void face_normals_kernel(const VertexNormalArrays a) {
  const int64_t f = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (f >= a.face_count) return;
  const int64_t i0 = a.faces[f * 3], i1 = a.faces[f * 3 + 1], i2 = a.faces[f * 3 + 2];
  const auto outside = [&](int64_t i) { return i < 0 || i >= a.vertex_count; };
  if (outside(i0) || outside(i1) || outside(i2)) return;  // skipped: no read or write outside the arrays
  float p0[3], e1[3], e2[3];
  for (int k = 0; k < 3; ++k) p0[k] = a.vertices[i0 * 3 + k];
  for (int k = 0; k < 3; ++k) {
    e1[k] = a.vertices[i1 * 3 + k] - p0[k];
    e2[k] = a.vertices[i2 * 3 + k] - p0[k];
  }
  const float n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
  for (const int64_t corner : {i0, i1, i2})
    for (int k = 0; k < 3; ++k) atomicAdd(a.sums + corner * 3 + k, n[k]);
}

__global__ void normalise_kernel(const VertexNormalArrays a) {
  const int64_t v = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (v >= a.vertex_count) return;
  const float x = a.sums[v * 3], y = a.sums[v * 3 + 1], z = a.sums[v * 3 + 2];
  const float length = sqrtf(x * x + y * y + z * z);
  const float scale = length > a.min_length ? 1.f / length : 0.f;
  a.normals[v * 3] = x * scale;
  a.normals[v * 3 + 1] = y * scale;
  a.normals[v * 3 + 2] = z * scale;
}

void check_launch(const char* what) {
  const cudaError_t status = cudaGetLastError();
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs vertex normals: ") + what + " launch failed: " +
                             cudaGetErrorString(status));
}

}  // namespace

void vertex_normals_forward(const VertexNormalArrays& a, cudaStream_t stream) {
  if (a.face_count > 0) {
    face_normals_kernel<<<unsigned((a.face_count + kThreads - 1) / kThreads), kThreads, 0, stream>>>(a);
    check_launch("face_normals_kernel");
  }
  if (a.vertex_count > 0) {
    normalise_kernel<<<unsigned((a.vertex_count + kThreads - 1) / kThreads), kThreads, 0, stream>>>(a);
    check_launch("normalise_kernel");
  }
}

}  // namespace sfgs::body::cuda_kernels
