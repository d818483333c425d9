// The fused GroupNorm + ReLU kernels. float rows of 128 channels (the avatar's layers) take the float4 kernels
// (below: a lane holds four adjacent channels). Otherwise a warp takes a row at a time (grid-stride), lane l
// holding channels l, l + 32, ..., l + 32 (K - 1) (K = C / 32 values, coalesced loads): a group's sums are warp
// sums of its slabs of 32 channels. The forward keeps the row in registers for the exact two-pass variance; the
// backward recomputes the normalised row from the saved moments and keeps each lane's column sums (gamma's, beta's
// and the bias's gradients) in registers across its rows, summed per block into one partial row.
#include <algorithm>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "ops/group_norm/constants.h"
#include "ops/group_norm/group_norm_kernels.h"
#include "cuda/launch_geometry.cuh"
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

// The float rows of kQuadChannels channels (the avatar's hidden layers): lane l holds channels 4l..4l+3 as one float4
// (one 512-byte load a row), so a group of S channels is S / 4 adjacent lanes and its sums take log2(S / 4)
// shuffles instead of five per 32-channel slab; the kernels keep fewer values a lane and more rows in flight.
constexpr int kQuadChannels = 128;
constexpr int kQuadBlocksPerSm = 6;  // 1,536 threads: sm_89's most, three quarters of sm_90's

// The sum over the aligned block of kGroupLanes lanes holding one group.
template <int kGroupLanes> __device__ __forceinline__ float group_sum(float v) {
#pragma unroll
  for (int offset = kGroupLanes / 2; offset > 0; offset /= 2) v += __shfl_xor_sync(0xffffffffu, v, offset);
  return v;
}

__device__ __forceinline__ float4 load_quad(const float* values, int lane) {
  return reinterpret_cast<const float4*>(values)[lane];
}

__device__ __forceinline__ float quad_sum(const float4& v) { return (v.x + v.y) + (v.z + v.w); }

template <int kGroupLanes>
__global__ void __launch_bounds__(kThreads, kQuadBlocksPerSm) forward_quad_kernel(const GroupNormArrays<float> a) {
  const int lane = threadIdx.x & 31;
  const float size = float(a.channels / a.groups);
  const float4 gamma = load_quad(a.gamma, lane), beta = load_quad(a.beta, lane);
  const float4 bias = a.bias ? load_quad(a.bias, lane) : make_float4(0, 0, 0, 0);
  const int64_t stride = (int64_t(gridDim.x) * blockDim.x) >> 5;
  int64_t row = (int64_t(blockIdx.x) * blockDim.x + threadIdx.x) >> 5;
  float4 next = row < a.rows ? load_quad(a.pre + row * kQuadChannels, lane) : make_float4(0, 0, 0, 0);
  for (; row < a.rows; row += stride) {
    const float4 h = make_float4(next.x + bias.x, next.y + bias.y, next.z + bias.z, next.w + bias.w);
    if (row + stride < a.rows) next = load_quad(a.pre + (row + stride) * kQuadChannels, lane);
    const float mean = group_sum<kGroupLanes>(quad_sum(h)) / size;
    const float4 d = make_float4(h.x - mean, h.y - mean, h.z - mean, h.w - mean);
    const float variance = group_sum<kGroupLanes>((d.x * d.x + d.y * d.y) + (d.z * d.z + d.w * d.w)) / size;
    const float rstd = inverse_deviation(variance, a.epsilon);
    reinterpret_cast<float4*>(a.out + row * kQuadChannels)[lane] =
        make_float4(activated(d.x * rstd, gamma.x, beta.x), activated(d.y * rstd, gamma.y, beta.y),
                    activated(d.z * rstd, gamma.z, beta.z), activated(d.w * rstd, gamma.w, beta.w));
    if (lane % kGroupLanes == 0) {
      a.mean[row * a.groups + lane / kGroupLanes] = mean;
      a.rstd[row * a.groups + lane / kGroupLanes] = rstd;
    }
  }
}

// One channel's share of the backward of a row: its gradient steps, the column sums it adds to.
struct QuadChannel {
  float xhat, gy, gxhat;
};

__device__ __forceinline__ QuadChannel quad_channel(float pre, float bias, float grad_out, float mean, float rstd,
                                                    float gamma, float beta) {
  const float xhat = (pre + bias - mean) * rstd;
  const float gy = affine_gradient(grad_out, xhat, gamma, beta);
  return {xhat, gy, gy * gamma};
}

template <int kGroupLanes>
__global__ void __launch_bounds__(kThreads, kBlocksPerSm) backward_quad_kernel(const GroupNormGradientArrays<float> a) {
  __shared__ float block_columns[3 * kQuadChannels];
  for (int i = threadIdx.x; i < 3 * kQuadChannels; i += blockDim.x) block_columns[i] = 0.0f;
  __syncthreads();

  const int lane = threadIdx.x & 31, group = lane / kGroupLanes;
  const float size = float(a.channels / a.groups);
  const float4 gamma = load_quad(a.gamma, lane), beta = load_quad(a.beta, lane);
  const float4 bias = a.bias ? load_quad(a.bias, lane) : make_float4(0, 0, 0, 0);
  float grad_gamma[4] = {}, grad_beta[4] = {}, grad_bias[4] = {};
  const int64_t stride = (int64_t(gridDim.x) * blockDim.x) >> 5;
  int64_t row = (int64_t(blockIdx.x) * blockDim.x + threadIdx.x) >> 5;
  float4 next_pre = make_float4(0, 0, 0, 0), next_grad = next_pre;
  if (row < a.rows) {
    next_pre = load_quad(a.pre + row * kQuadChannels, lane);
    next_grad = load_quad(a.grad_out + row * kQuadChannels, lane);
  }
  for (; row < a.rows; row += stride) {
    const float mean = a.mean[row * a.groups + group], rstd = a.rstd[row * a.groups + group];
    const QuadChannel c[4] = {quad_channel(next_pre.x, bias.x, next_grad.x, mean, rstd, gamma.x, beta.x),
                              quad_channel(next_pre.y, bias.y, next_grad.y, mean, rstd, gamma.y, beta.y),
                              quad_channel(next_pre.z, bias.z, next_grad.z, mean, rstd, gamma.z, beta.z),
                              quad_channel(next_pre.w, bias.w, next_grad.w, mean, rstd, gamma.w, beta.w)};
    if (row + stride < a.rows) {
      next_pre = load_quad(a.pre + (row + stride) * kQuadChannels, lane);
      next_grad = load_quad(a.grad_out + (row + stride) * kQuadChannels, lane);
    }
    float s1 = 0, s2 = 0;
#pragma unroll
    for (int k = 0; k < 4; ++k) {
      s1 += c[k].gxhat;
      s2 += c[k].gxhat * c[k].xhat;
      grad_gamma[k] += c[k].gy * c[k].xhat;
      grad_beta[k] += c[k].gy;
    }
    const float m1 = group_sum<kGroupLanes>(s1) / size, m2 = group_sum<kGroupLanes>(s2) / size;
    float g[4];
#pragma unroll
    for (int k = 0; k < 4; ++k) {
      g[k] = normalised_gradient(c[k].gxhat, c[k].xhat, rstd, m1, m2);
      grad_bias[k] += g[k];
    }
    reinterpret_cast<float4*>(a.grad_pre + row * kQuadChannels)[lane] = make_float4(g[0], g[1], g[2], g[3]);
  }
#pragma unroll
  for (int k = 0; k < 4; ++k) {
    const int c = 4 * lane + k;
    atomicAdd(block_columns + c, grad_gamma[k]);
    atomicAdd(block_columns + kQuadChannels + c, grad_beta[k]);
    atomicAdd(block_columns + 2 * kQuadChannels + c, grad_bias[k]);
  }
  __syncthreads();
  float* partial = a.column_partials + int64_t(blockIdx.x) * 3 * kQuadChannels;
  for (int i = threadIdx.x; i < 3 * kQuadChannels; i += blockDim.x) partial[i] = block_columns[i];
}

using cuda_launch::aligned16;

// Lanes a group takes in the float4 kernels, or 0 where they do not apply (other widths, misaligned arrays).
template <typename Arrays> int quad_group_lanes(const Arrays& a) {
  if (a.channels != kQuadChannels || a.groups <= 0 || a.channels % a.groups != 0) return 0;
  const int lanes = a.channels / a.groups / 4;
  if (lanes != 8 && lanes != 16 && lanes != 32) return 0;
  return aligned16(a.pre) && aligned16(a.gamma) && aligned16(a.beta) && aligned16(a.bias) ? lanes : 0;
}

constexpr const char* kOwner = "group_norm_relu";

void check_launch(const char* kernel) { cuda_launch::check_launch(kOwner, kernel); }

// Blocks of a row-per-warp launch, at most `blocks_per_sm` a multiprocessor.
int64_t blocks_for(int64_t rows, int device, int blocks_per_sm = kBlocksPerSm) {
  return cuda_launch::grid_stride_blocks(rows, kWarpsPerBlock, blocks_per_sm, device, kOwner);
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
    case 1:
      return Launch<T, 1>::run(a, blocks, stream);
    case 2:
      return Launch<T, 2>::run(a, blocks, stream);
    case 3:
      return Launch<T, 3>::run(a, blocks, stream);
    case 4:
      return Launch<T, 4>::run(a, blocks, stream);
    case 5:
      return Launch<T, 5>::run(a, blocks, stream);
    case 6:
      return Launch<T, 6>::run(a, blocks, stream);
    case 7:
      return Launch<T, 7>::run(a, blocks, stream);
    case 8:
      return Launch<T, 8>::run(a, blocks, stream);
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
  if constexpr (std::is_same_v<T, float>) {
    if (const int lanes = quad_group_lanes(a); lanes > 0 && aligned16(a.out)) {
      const unsigned blocks = unsigned(blocks_for(a.rows, device, kQuadBlocksPerSm));
      if (lanes == 8)
        forward_quad_kernel<8><<<blocks, kThreads, 0, stream>>>(a);
      else if (lanes == 16)
        forward_quad_kernel<16><<<blocks, kThreads, 0, stream>>>(a);
      else
        forward_quad_kernel<32><<<blocks, kThreads, 0, stream>>>(a);
      return check_launch("forward_quad_kernel");
    }
  }
  with_lane_values<ForwardLaunch, T>(a, unsigned(blocks_for(a.rows, device)), stream);
}

template <typename T> void backward(const GroupNormGradientArrays<T>& a, int, cudaStream_t stream) {
  if constexpr (std::is_same_v<T, float>) {
    if (const int lanes = quad_group_lanes(a); lanes > 0 && aligned16(a.grad_out) && aligned16(a.grad_pre)) {
      const unsigned blocks = unsigned(a.partial_rows);
      if (lanes == 8)
        backward_quad_kernel<8><<<blocks, kThreads, 0, stream>>>(a);
      else if (lanes == 16)
        backward_quad_kernel<16><<<blocks, kThreads, 0, stream>>>(a);
      else
        backward_quad_kernel<32><<<blocks, kThreads, 0, stream>>>(a);
      return check_launch("backward_quad_kernel");
    }
  }
  with_lane_values<BackwardLaunch, T>(a, unsigned(a.partial_rows), stream);
}

template void forward<float>(const GroupNormArrays<float>&, int, cudaStream_t);
template void forward<double>(const GroupNormArrays<double>&, int, cudaStream_t);
template void backward<float>(const GroupNormGradientArrays<float>&, int, cudaStream_t);
template void backward<double>(const GroupNormGradientArrays<double>&, int, cudaStream_t);

}  // namespace sfgs::group_norm::cuda_kernels
