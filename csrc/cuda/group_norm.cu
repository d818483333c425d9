// The fused GroupNorm + ReLU kernels. A warp takes a row at a time (grid-stride), lane l holding channels
// l, l + 32, ..., l + 32 (K - 1) (K = C / 32 values, coalesced loads): a group's sums are warp sums of its slabs of
// 32 channels. The forward keeps the row in registers for the exact two-pass variance; the backward recomputes the
// normalised row from the saved moments and keeps each lane's column sums (gamma's, beta's and the bias's
// gradients) in registers across its rows, summed per block into one partial row.
#include <algorithm>
#include <stdexcept>
#include <string>

#include "common/constants.h"
#include "cuda/group_norm_kernels.h"
#include "cuda/warp_utils.cuh"

namespace sfgs::group_norm::cuda_kernels {
namespace {

constexpr int kWarpsPerBlock = 8;
constexpr int kThreads = 32 * kWarpsPerBlock;
constexpr int kBlocksPerSm = 4;  // resident blocks a multiprocessor keeps busy (grid-stride beyond)
constexpr int kMaxLaneValues = int(kGroupNormMaxChannels / 32);

using splat::cuda_kernels::warp_sum;

// Per slab k, the mean over its group of the slabs' warp sums `slab` (a group is `slabs` consecutive slabs of 32
// channels): every index is known at compile time, so the row stays in registers. `mean` must not be `slab`.
template <typename T, int K>
__device__ __forceinline__ void group_means(const T (&slab)[K], int slabs, T size, T (&mean)[K]) {
#pragma unroll
  for (int k = 0; k < K; ++k) {
    T sum = 0;
#pragma unroll
    for (int j = 0; j < K; ++j)
      if (j / slabs == k / slabs) sum += slab[j];
    mean[k] = sum / size;
  }
}

// A lane's values of row `row`: channels lane, lane + 32, ... (each load coalesced across the warp).
template <typename T, int K>
__device__ __forceinline__ void load_row(const T* rows, int64_t row, int channels, int lane, T (&values)[K]) {
  const T* r = rows + row * channels;
#pragma unroll
  for (int k = 0; k < K; ++k) values[k] = r[lane + 32 * k];
}

// A lane's channels of the layer's gamma, beta and bias (0 without a bias), for both kernels' arrays.
template <typename Arrays, typename T, int K>
__device__ __forceinline__ void load_affine(const Arrays& a, int lane, T (&gamma)[K], T (&beta)[K], T (&bias)[K]) {
#pragma unroll
  for (int k = 0; k < K; ++k) {
    const int c = lane + 32 * k;
    gamma[k] = a.gamma[c];
    beta[k] = a.beta[c];
    bias[k] = a.bias ? a.bias[c] : T(0);
  }
}

template <typename T, int K>
__global__ void __launch_bounds__(kThreads, kBlocksPerSm) forward_kernel(const GroupNormArrays<T> a) {
  const int lane = threadIdx.x & 31, slabs = K / a.groups;
  const T size = T(a.channels / a.groups);
  T gamma[K], beta[K], bias[K];
  load_affine(a, lane, gamma, beta, bias);
  const int64_t stride = (int64_t(gridDim.x) * blockDim.x) >> 5;
  int64_t row = (int64_t(blockIdx.x) * blockDim.x + threadIdx.x) >> 5;
  // The next row is loaded while this one is reduced: a warp has two rows' loads in flight.
  T next[K];
  if (row < a.rows) load_row<T, K>(a.pre, row, a.channels, lane, next);
  for (; row < a.rows; row += stride) {
    T h[K], sums[K], mean[K], rstd[K];
#pragma unroll
    for (int k = 0; k < K; ++k) h[k] = next[k] + bias[k];
    if (row + stride < a.rows) load_row<T, K>(a.pre, row + stride, a.channels, lane, next);
#pragma unroll
    for (int k = 0; k < K; ++k) sums[k] = warp_sum(h[k]);
    group_means(sums, slabs, size, mean);
#pragma unroll
    for (int k = 0; k < K; ++k) {
      const T d = h[k] - mean[k];
      sums[k] = warp_sum(d * d);
    }
    group_means(sums, slabs, size, rstd);  // the variance, for now
    T* out = a.out + row * a.channels;
#pragma unroll
    for (int k = 0; k < K; ++k) {
      rstd[k] = inverse_deviation(rstd[k], a.epsilon);
      out[lane + 32 * k] = activated((h[k] - mean[k]) * rstd[k], gamma[k], beta[k]);
      if (lane == 0 && k % slabs == 0) {
        a.mean[row * a.groups + k / slabs] = mean[k];
        a.rstd[row * a.groups + k / slabs] = rstd[k];
      }
    }
  }
}

template <typename T, int K>
__global__ void __launch_bounds__(kThreads, kBlocksPerSm) backward_kernel(const GroupNormGradientArrays<T> a) {
  extern __shared__ unsigned char shared_bytes[];
  T* block_columns = reinterpret_cast<T*>(shared_bytes);  // 3 x channels
  for (int i = threadIdx.x; i < 3 * a.channels; i += blockDim.x) block_columns[i] = T(0);
  __syncthreads();

  const int lane = threadIdx.x & 31, slabs = K / a.groups;
  const T size = T(a.channels / a.groups);
  T gamma[K], beta[K], bias[K], grad_gamma[K] = {}, grad_beta[K] = {}, grad_bias[K] = {};
  load_affine(a, lane, gamma, beta, bias);
  const int64_t stride = (int64_t(gridDim.x) * blockDim.x) >> 5;
  int64_t row = (int64_t(blockIdx.x) * blockDim.x + threadIdx.x) >> 5;
  T next_pre[K], next_grad[K];  // the next row's, loaded while this one is reduced
  if (row < a.rows) {
    load_row<T, K>(a.pre, row, a.channels, lane, next_pre);
    load_row<T, K>(a.grad_out, row, a.channels, lane, next_grad);
  }
  for (; row < a.rows; row += stride) {
    T xhat[K], rstd[K], gxhat[K], sums1[K], sums2[K], m1[K], m2[K];
#pragma unroll
    for (int k = 0; k < K; ++k) {
      const int64_t moment = row * a.groups + k / slabs;
      rstd[k] = a.rstd[moment];
      xhat[k] = (next_pre[k] + bias[k] - a.mean[moment]) * rstd[k];
      const T gy = affine_gradient(next_grad[k], xhat[k], gamma[k], beta[k]);
      grad_gamma[k] += gy * xhat[k];
      grad_beta[k] += gy;
      gxhat[k] = gy * gamma[k];
    }
    if (row + stride < a.rows) {
      load_row<T, K>(a.pre, row + stride, a.channels, lane, next_pre);
      load_row<T, K>(a.grad_out, row + stride, a.channels, lane, next_grad);
    }
#pragma unroll
    for (int k = 0; k < K; ++k) {
      sums1[k] = warp_sum(gxhat[k]);
      sums2[k] = warp_sum(gxhat[k] * xhat[k]);
    }
    group_means(sums1, slabs, size, m1);
    group_means(sums2, slabs, size, m2);
    T* grad_pre = a.grad_pre + row * a.channels;
#pragma unroll
    for (int k = 0; k < K; ++k) {
      const T g = normalised_gradient(gxhat[k], xhat[k], rstd[k], m1[k], m2[k]);
      grad_pre[lane + 32 * k] = g;
      grad_bias[k] += g;
    }
  }
#pragma unroll
  for (int k = 0; k < K; ++k) {
    const int c = lane + 32 * k;
    atomicAdd(block_columns + c, grad_gamma[k]);
    atomicAdd(block_columns + a.channels + c, grad_beta[k]);
    atomicAdd(block_columns + 2 * a.channels + c, grad_bias[k]);
  }
  __syncthreads();
  T* partial = a.column_partials + int64_t(blockIdx.x) * 3 * a.channels;
  for (int i = threadIdx.x; i < 3 * a.channels; i += blockDim.x) partial[i] = block_columns[i];
}

void check_launch(const char* what) {
  const cudaError_t status = cudaGetLastError();
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs group_norm_relu: ") + what +
                             " launch failed: " + cudaGetErrorString(status));
}

int64_t resident_blocks(int device) {
  int multiprocessors = 0;
  if (cudaDeviceGetAttribute(&multiprocessors, cudaDevAttrMultiProcessorCount, device) != cudaSuccess)
    throw std::runtime_error("sfgs group_norm_relu: cannot read the multiprocessor count of CUDA device " +
                             std::to_string(device));
  return int64_t(multiprocessors) * kBlocksPerSm;
}

int64_t blocks_for(int64_t rows, int device) {
  return std::max<int64_t>(1, std::min((rows + kWarpsPerBlock - 1) / kWarpsPerBlock, resident_blocks(device)));
}

template <typename T, int K> struct ForwardLaunch {
  static void run(const GroupNormArrays<T>& a, unsigned blocks, cudaStream_t stream) {
    forward_kernel<T, K><<<blocks, kThreads, 0, stream>>>(a);
    check_launch("forward_kernel");
  }
};

template <typename T, int K> struct BackwardLaunch {
  static void run(const GroupNormGradientArrays<T>& a, unsigned blocks, cudaStream_t stream) {
    backward_kernel<T, K><<<blocks, kThreads, size_t(3) * a.channels * sizeof(T), stream>>>(a);
    check_launch("backward_kernel");
  }
};

// Launch<T, K>::run for the row's values a lane, K = channels / 32.
template <template <typename, int> class Launch, typename T, typename Arrays>
void with_lane_values(const Arrays& a, unsigned blocks, cudaStream_t stream) {
  switch (a.channels / 32) {
    case 1: return Launch<T, 1>::run(a, blocks, stream);
    case 2: return Launch<T, 2>::run(a, blocks, stream);
    case 3: return Launch<T, 3>::run(a, blocks, stream);
    case 4: return Launch<T, 4>::run(a, blocks, stream);
    case 5: return Launch<T, 5>::run(a, blocks, stream);
    case 6: return Launch<T, 6>::run(a, blocks, stream);
    case 7: return Launch<T, 7>::run(a, blocks, stream);
    case 8: return Launch<T, 8>::run(a, blocks, stream);
  }
  throw std::runtime_error("sfgs group_norm_relu: unsupported channel count " + std::to_string(a.channels));
}
static_assert(kMaxLaneValues == 8, "with_lane_values instantiates 1 to 8 values a lane");

}  // namespace

bool supports(int64_t channels, int64_t groups) {
  return groups > 0 && channels > 0 && channels <= kGroupNormMaxChannels && channels % groups == 0 &&
         (channels / groups) % 32 == 0;
}

int64_t backward_blocks(int64_t rows, int device) { return blocks_for(rows, device); }

template <typename T> void forward(const GroupNormArrays<T>& a, int device, cudaStream_t stream) {
  if (a.rows == 0) return;
  with_lane_values<ForwardLaunch, T>(a, unsigned(blocks_for(a.rows, device)), stream);
}

template <typename T> void backward(const GroupNormGradientArrays<T>& a, int, cudaStream_t stream) {
  with_lane_values<BackwardLaunch, T>(a, unsigned(a.partial_rows), stream);
}

template void forward<float>(const GroupNormArrays<float>&, int, cudaStream_t);
template void forward<double>(const GroupNormArrays<double>&, int, cudaStream_t);
template void backward<float>(const GroupNormGradientArrays<float>&, int, cudaStream_t);
template void backward<double>(const GroupNormGradientArrays<double>&, int, cudaStream_t);

}  // namespace sfgs::group_norm::cuda_kernels
