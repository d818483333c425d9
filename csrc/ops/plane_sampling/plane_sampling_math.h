#pragma once
// The arithmetic of the fixed-point plane sampling's backward (plane_sampling.h), shared by the CPU backend
// (csrc/ops/plane_sampling/plane_sampling_cpu.cpp) and the CUDA kernel (csrc/ops/plane_sampling/plane_sampling.cu):
// each texel's gradient is a gather over the reads of it, listed in chunks of at most kPlaneReadChunk reads of one
// texel.
#include <cstdint>

#include "common/host_device.h"

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
};

// Chunk k's share of the gradient of channel c of its texel: the weighted sum of the incoming gradients of its
// reads, in the order listed (fixed when the reads were made).
template <typename T> SFGS_HD T chunk_gradient(const PlaneGradientArrays<T>& a, int64_t k, int64_t c) {
  const int64_t plane = a.chunk_rows[k] / a.texels, row_width = a.planes * a.channels;
  T sum = 0;
  for (int32_t e = a.chunk_begins[k]; e < a.chunk_ends[k]; ++e)
    sum += a.weights[e] * a.grad_features[int64_t(a.points[e]) * row_width + plane * a.channels + c];
  return sum;
}

// Where chunk k's share for channel c goes in grad_planes.
template <typename T> SFGS_HD int64_t gradient_index(const PlaneGradientArrays<T>& a, int64_t k, int64_t c) {
  const int64_t plane = a.chunk_rows[k] / a.texels, texel = a.chunk_rows[k] % a.texels;
  return (plane * a.channels + c) * a.texels + texel;
}

}  // namespace sfgs::plane_sampling
