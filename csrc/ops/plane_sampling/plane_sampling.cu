// The planes' backward: a warp per chunk of at most kPlaneReadChunk reads of one texel, lane c summing channel c
// (the reads' incoming gradients are C contiguous values: one coalesced load per read), then one atomic add per
// channel (a texel's chunks are few, so the adds rarely meet).
#include <stdexcept>
#include <string>

#include "ops/plane_sampling/plane_sampling_kernels.h"
#include "ops/plane_sampling/constants.h"

namespace sfgs::plane_sampling::cuda_kernels {
namespace {

constexpr int kWarp = 32;
constexpr int kWarpsPerBlock = 8;

template <typename T> __global__ void gradient_kernel(PlaneGradientArrays<T> a) {
  const int64_t k = int64_t(blockIdx.x) * kWarpsPerBlock + threadIdx.x / kWarp;
  if (k >= a.chunks || !chunk_texel_valid(a, k)) return;
  for (int64_t c = threadIdx.x % kWarp; c < a.channels; c += kWarp)
    atomicAdd(a.grad_planes + gradient_index(a, k, c), chunk_gradient(a, k, c));
}

}  // namespace

template <typename T> void gradient(const PlaneGradientArrays<T>& a, cudaStream_t stream) {
  const int64_t blocks = (a.chunks + kWarpsPerBlock - 1) / kWarpsPerBlock;
  gradient_kernel<T><<<unsigned(blocks), kWarpsPerBlock * kWarp, 0, stream>>>(a);
  const cudaError_t status = cudaGetLastError();
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("plane_sampling gradient_kernel launch: ") + cudaGetErrorString(status));
}

template void gradient<float>(const PlaneGradientArrays<float>&, cudaStream_t);
template void gradient<double>(const PlaneGradientArrays<double>&, cudaStream_t);

}  // namespace sfgs::plane_sampling::cuda_kernels
