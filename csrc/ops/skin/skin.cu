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
  if (i < g.count) skin_one_backward(g, i, [](int64_t, T) {});
}

// The input gradients, and the block's share of the transforms' gradient summed in shared memory (J x 12 values)
// into its row of block_sums.
template <typename T>
__global__ void skin_backward_with_transforms_kernel(const SkinGradientArrays<T> g, T* block_sums) {
  extern __shared__ unsigned char shared_bytes[];
  T* sums = reinterpret_cast<T*>(shared_bytes);
  const int values = int(g.joint_count) * kTransformValues;
  for (int v = threadIdx.x; v < values; v += blockDim.x) sums[v] = T(0);
  __syncthreads();
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i < g.count) skin_one_backward(g, i, [&](int64_t value, T share) { atomicAdd(sums + value, share); });
  __syncthreads();
  for (int v = threadIdx.x; v < values; v += blockDim.x) block_sums[int64_t(blockIdx.x) * values + v] = sums[v];
}

// The transforms' gradient: each value's block sums added in block order.
template <typename T> __global__ void sum_block_rows_kernel(const T* block_sums, int64_t blocks, int values, T* out) {
  const int v = int(blockIdx.x) * blockDim.x + threadIdx.x;
  if (v >= values) return;
  T sum = T(0);
  for (int64_t b = 0; b < blocks; ++b) sum += block_sums[b * values + v];
  out[v] = sum;
}

unsigned blocks_for(int64_t count) { return unsigned((count + kThreads - 1) / kThreads); }

}  // namespace

template <typename T> int64_t backward_scratch_values(const SkinGradientArrays<T>& arrays) {
  return arrays.grad_transforms == nullptr ? 0
                                           : int64_t(blocks_for(arrays.count)) * arrays.joint_count * kTransformValues;
}

template <typename T> void skin_forward(const SkinArrays<T>& arrays, cudaStream_t stream) {
  if (arrays.count == 0) return;
  skin_forward_kernel<T><<<blocks_for(arrays.count), kThreads, 0, stream>>>(arrays);
  cuda_launch::check_launch("skinning", "skin_forward_kernel");
}

template <typename T> void skin_backward(const SkinGradientArrays<T>& arrays, T* scratch, cudaStream_t stream) {
  const int values = int(arrays.joint_count) * kTransformValues;
  if (arrays.grad_transforms != nullptr && arrays.count == 0) {
    cudaMemsetAsync(arrays.grad_transforms, 0, size_t(values) * sizeof(T), stream);
    cuda_launch::check_launch("skinning", "the transforms' gradient of no Gaussians");
    return;
  }
  if (arrays.count == 0) return;
  const unsigned blocks = blocks_for(arrays.count);
  if (arrays.grad_transforms == nullptr) {
    skin_backward_kernel<T><<<blocks, kThreads, 0, stream>>>(arrays);
    cuda_launch::check_launch("skinning", "skin_backward_kernel");
    return;
  }
  skin_backward_with_transforms_kernel<T><<<blocks, kThreads, size_t(values) * sizeof(T), stream>>>(arrays, scratch);
  cuda_launch::check_launch("skinning", "skin_backward_with_transforms_kernel");
  sum_block_rows_kernel<T><<<unsigned((values + kThreads - 1) / kThreads), kThreads, 0, stream>>>(
      scratch, int64_t(blocks), values, arrays.grad_transforms);
  cuda_launch::check_launch("skinning", "sum_block_rows_kernel");
}

template int64_t backward_scratch_values<float>(const SkinGradientArrays<float>&);
template int64_t backward_scratch_values<double>(const SkinGradientArrays<double>&);
template void skin_forward<float>(const SkinArrays<float>&, cudaStream_t);
template void skin_forward<double>(const SkinArrays<double>&, cudaStream_t);
template void skin_backward<float>(const SkinGradientArrays<float>&, float*, cudaStream_t);
template void skin_backward<double>(const SkinGradientArrays<double>&, double*, cudaStream_t);

}  // namespace sfgs::skin::cuda_kernels
