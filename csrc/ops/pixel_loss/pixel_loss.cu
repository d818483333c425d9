// The fused pixel-loss kernels: a thread per pixel. The forward sums each block's pixels in shared memory into one
// partial row (divided by the terms' counts, so the rows add up to the means); the backward writes each pixel's
// gradient, reading its neighbours' differences itself.
#include "cuda/launch_geometry.cuh"
#include "ops/pixel_loss/pixel_loss_kernels.h"

namespace sfgs::pixel_loss::cuda_kernels {
namespace {

constexpr int kThreads = 256;

template <typename T> __global__ void __launch_bounds__(kThreads) forward_kernel(const PixelLossArrays<T> a) {
  __shared__ T block_sums[kSums][kThreads];
  const int64_t pixel = int64_t(blockIdx.x) * kThreads + threadIdx.x;
  T sums[kSums] = {0, 0, 0, 0};
  if (pixel < int64_t(a.height) * a.width) pixel_sums(a, int(pixel / a.width), int(pixel % a.width), sums);
  for (int k = 0; k < kSums; ++k) block_sums[k][threadIdx.x] = sums[k];
  __syncthreads();
  for (int half = kThreads / 2; half > 0; half >>= 1) {
    if (threadIdx.x < half)
      for (int k = 0; k < kSums; ++k) block_sums[k][threadIdx.x] += block_sums[k][threadIdx.x + half];
    __syncthreads();
  }
  if (threadIdx.x < kSums)
    a.partial_sums[int64_t(blockIdx.x) * kSums + threadIdx.x] =
        block_sums[threadIdx.x][0] / term_count<T>(threadIdx.x, a.height, a.width);
}

template <typename T> __global__ void __launch_bounds__(kThreads) backward_kernel(const PixelLossGradientArrays<T> a) {
  const int64_t pixel = int64_t(blockIdx.x) * kThreads + threadIdx.x;
  if (pixel < int64_t(a.height) * a.width) pixel_gradient(a, int(pixel / a.width), int(pixel % a.width));
}

unsigned blocks_for(int height, int width) { return unsigned((int64_t(height) * width + kThreads - 1) / kThreads); }

}  // namespace

int64_t partials(int height, int width) { return blocks_for(height, width); }

template <typename T> void forward(const PixelLossArrays<T>& a, cudaStream_t stream) {
  forward_kernel<T><<<blocks_for(a.height, a.width), kThreads, 0, stream>>>(a);
  cuda_launch::check_launch("pixel_losses", "forward_kernel");
}

template <typename T> void backward(const PixelLossGradientArrays<T>& a, cudaStream_t stream) {
  backward_kernel<T><<<blocks_for(a.height, a.width), kThreads, 0, stream>>>(a);
  cuda_launch::check_launch("pixel_losses", "backward_kernel");
}

template void forward<float>(const PixelLossArrays<float>&, cudaStream_t);
template void forward<double>(const PixelLossArrays<double>&, cudaStream_t);
template void backward<float>(const PixelLossGradientArrays<float>&, cudaStream_t);
template void backward<double>(const PixelLossGradientArrays<double>&, cudaStream_t);

}  // namespace sfgs::pixel_loss::cuda_kernels
