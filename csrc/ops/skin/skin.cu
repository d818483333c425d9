#include "cuda/launch_geometry.cuh"
#include "ops/skin/skin_kernels.h"

namespace sfgs::skin::cuda_kernels {
namespace {

constexpr int kThreads = 256;

template <typename T> __global__ void skin_forward_kernel(const SkinArrays<T> s) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i < s.count) skin_one(s, i);
}

template <typename T> __global__ void skin_backward_kernel(const SkinGradientArrays<T> g) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i < g.count) skin_one_backward(g, i);
}

unsigned blocks_for(int64_t count) { return unsigned((count + kThreads - 1) / kThreads); }

}  // namespace

template <typename T> void skin_forward(const SkinArrays<T>& arrays, cudaStream_t stream) {
  if (arrays.count == 0) return;
  skin_forward_kernel<T><<<blocks_for(arrays.count), kThreads, 0, stream>>>(arrays);
  cuda_launch::check_launch("skinning", "skin_forward_kernel");
}

template <typename T> void skin_backward(const SkinGradientArrays<T>& arrays, cudaStream_t stream) {
  if (arrays.count == 0) return;
  skin_backward_kernel<T><<<blocks_for(arrays.count), kThreads, 0, stream>>>(arrays);
  cuda_launch::check_launch("skinning", "skin_backward_kernel");
}

template void skin_forward<float>(const SkinArrays<float>&, cudaStream_t);
template void skin_forward<double>(const SkinArrays<double>&, cudaStream_t);
template void skin_backward<float>(const SkinGradientArrays<float>&, cudaStream_t);
template void skin_backward<double>(const SkinGradientArrays<double>&, cudaStream_t);

}  // namespace sfgs::skin::cuda_kernels
