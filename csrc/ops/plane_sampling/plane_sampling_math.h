#pragma once
// The arithmetic of the fixed-point plane sampling's backward (plane_sampling.h), shared by the CPU backend
// (csrc/ops/plane_sampling/plane_sampling_cpu.cpp) and the CUDA kernel (csrc/ops/plane_sampling/plane_sampling.cu):
// each texel's gradient is a gather over the reads of it, listed in chunks of at most kPlaneReadChunk reads of one
// texel.
#include <cstdint>
#include <limits>

#include "common/host_device.h"
#include "ops/plane_sampling/constants.h"

namespace sfgs::plane_sampling {

template <typename T> struct PlaneGradientArrays {
  const T* grad_features;       // (N, P C): the incoming gradient of the sampled features, plane-major columns
  const int32_t* chunk_rows;    // (K) the texel of each chunk: plane * texels + y * width + x
  const int32_t* chunk_begins;  // (K) its first read
  const int32_t* chunk_ends;    // (K) one past its last read
  const int32_t* points;        // (E) the point of each read
  const T* weights;             // (E) its bilinear weight
  T* grad_planes;               // (P, C, H, W), zero on entry; chunks add to it
  int64_t chunks, planes, channels, texels;
  int64_t points_count, reads;  // N (the incoming gradient's rows) and E
};

// Chunk k's reads and texel lie within the arrays. Reads plane_reads made always do; the CPU op refuses others, and
// the CUDA kernel, which cannot check them without reading the device, gives such a chunk NaN or skips it: nothing
// outside the arrays is read or written.
template <typename T> SFGS_HD bool chunk_reads_valid(const PlaneGradientArrays<T>& a, int64_t k) {
  return a.chunk_begins[k] >= 0 && a.chunk_begins[k] <= a.chunk_ends[k] && a.chunk_ends[k] <= a.reads;
}
template <typename T> SFGS_HD bool chunk_texel_valid(const PlaneGradientArrays<T>& a, int64_t k) {
  return a.chunk_rows[k] >= 0 && a.chunk_rows[k] < a.planes * a.texels;
}

// Chunk k's share of the gradient of channel c of its texel: the weighted sum of the incoming gradients of its
// reads, in the order listed (fixed when the reads were made).
// A chunk whose reads or points lie outside the arrays gives NaN (chunk_reads_valid).
template <typename T> SFGS_HD T chunk_gradient(const PlaneGradientArrays<T>& a, int64_t k, int64_t c) {
  if (!chunk_reads_valid(a, k)) return std::numeric_limits<T>::quiet_NaN();
  const int64_t plane = a.chunk_rows[k] / a.texels, row_width = a.planes * a.channels;
  T sum = 0;
  for (int32_t e = a.chunk_begins[k]; e < a.chunk_ends[k]; ++e) {
    const int32_t point = a.points[e];
    if (point < 0 || point >= a.points_count) return std::numeric_limits<T>::quiet_NaN();
    sum += a.weights[e] * a.grad_features[int64_t(point) * row_width + plane * a.channels + c];
  }
  return sum;
}

// Where chunk k's share for channel c goes in grad_planes; only for a chunk whose texel is valid (chunk_texel_valid).
template <typename T> SFGS_HD int64_t gradient_index(const PlaneGradientArrays<T>& a, int64_t k, int64_t c) {
  const int64_t plane = a.chunk_rows[k] / a.texels, texel = a.chunk_rows[k] % a.texels;
  return (plane * a.channels + c) * a.texels + texel;
}

}  // namespace sfgs::plane_sampling
