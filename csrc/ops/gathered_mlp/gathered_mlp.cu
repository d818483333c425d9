// The gathered MLP's kernel (gathered_mlp_kernels.h). Each warp takes 16 rows at a time: it gathers their first
// layer (row share + group share, ReLU) into shared memory as half, multiplies by the hidden weights on tensor cores
// (wmma 16x16x16, float accumulation), and reduces the ReLU'd hidden layer against the few output weights, two
// lanes per row. The block loads the hidden and output weights into shared memory once and its warps then stride
// over the rows, so the weights cost one read per block and the rows one read each.
#include <cuda_fp16.h>
#include <mma.h>

#include <algorithm>
#include <stdexcept>
#include <string>

#include "ops/gathered_mlp/gathered_mlp_kernels.h"

namespace sfgs::gathered_mlp::cuda_kernels {
namespace {

constexpr int kWidth = kFusedWidth;
constexpr int kTile = 16;  // wmma tile edge, and rows per warp pass
constexpr int kTilesAcross = kWidth / kTile;
constexpr int kWarps = 4;
constexpr int kThreads = kWarps * 32;
constexpr int kWeightStride = kWidth + 8;  // halves: rows shifted across banks; wmma needs a multiple of 8
constexpr int kInputStride = kWidth + 8;   // halves
constexpr int kHiddenStride = kWidth + 4;  // floats: a multiple of 4, as wmma needs

// Shared memory, in bytes; every wmma pointer must be 32-byte aligned, so every region is.
constexpr int kWeightBytes = kWidth * kWeightStride * 2;
constexpr int kHiddenBiasBytes = kWidth * 4;
constexpr int kOutputWeightBytes = kFusedMaxOutputs * kWidth * 4;
constexpr int kOutputBiasBytes = 32;
constexpr int kWarpScratchBytes = kTile * kHiddenStride * 4;  // the hidden layer (float); the input (half) before it
constexpr int kSharedBytes =
    kWeightBytes + kHiddenBiasBytes + kOutputWeightBytes + kOutputBiasBytes + kWarps * kWarpScratchBytes;
static_assert(kWeightBytes % 32 == 0 && kHiddenBiasBytes % 32 == 0 && kOutputWeightBytes % 32 == 0 &&
                  kWarpScratchBytes % 32 == 0,
              "shared regions must stay 32-byte aligned for wmma");
static_assert(kTile * kInputStride * 2 <= kWarpScratchBytes, "the half input must fit the warp's scratch");
static_assert(kWidth == 32 * 4, "each lane gathers four columns of a row");

__global__ void __launch_bounds__(kThreads) gathered_mlp_kernel(const GatheredMlpArrays a) {
  using namespace nvcuda;
  extern __shared__ __align__(32) unsigned char shared[];
  __half* weight = reinterpret_cast<__half*>(shared);
  float* hidden_bias = reinterpret_cast<float*>(shared + kWeightBytes);
  float* output_weight = hidden_bias + kWidth;
  float* output_bias = output_weight + kFusedMaxOutputs * kWidth;
  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32;
  unsigned char* scratch =
      shared + kWeightBytes + kHiddenBiasBytes + kOutputWeightBytes + kOutputBiasBytes + warp * kWarpScratchBytes;
  __half* input = reinterpret_cast<__half*>(scratch);
  float* hidden = reinterpret_cast<float*>(scratch);

  const __half* hidden_weight = reinterpret_cast<const __half*>(a.hidden_weight);
  for (int i = threadIdx.x; i < kWidth * kWidth; i += kThreads)
    weight[(i / kWidth) * kWeightStride + i % kWidth] = hidden_weight[i];
  for (int i = threadIdx.x; i < kWidth; i += kThreads) hidden_bias[i] = a.hidden_bias[i];
  for (int i = threadIdx.x; i < a.outputs * kWidth; i += kThreads) output_weight[i] = a.output_weight[i];
  if (threadIdx.x < a.outputs) output_bias[threadIdx.x] = a.output_bias[threadIdx.x];
  __syncthreads();

  const __half* row_inputs = reinterpret_cast<const __half*>(a.row_inputs);
  const int64_t passes = (a.rows + kTile - 1) / kTile;
  for (int64_t pass = int64_t(blockIdx.x) * kWarps + warp; pass < passes; pass += int64_t(gridDim.x) * kWarps) {
    const int64_t first_row = pass * kTile;
    // First layer: ReLU(row share + group share) as half; rows past the end and rows of an invalid group are zero
    // here and NaN at the output.
    const int column = lane * 4;
    for (int r = 0; r < kTile; ++r) {
      const int64_t row = first_row + r;
      const int32_t group = row < a.rows ? a.groups[row] : -1;
      __half2 low = __float2half2_rn(0.f), high = low;
      if (group >= 0 && group < a.group_count) {
        const uint2 packed = *reinterpret_cast<const uint2*>(row_inputs + row * kWidth + column);
        const float2 p01 = __half22float2(*reinterpret_cast<const __half2*>(&packed.x));
        const float2 p23 = __half22float2(*reinterpret_cast<const __half2*>(&packed.y));
        const float4 q = *reinterpret_cast<const float4*>(a.group_inputs + int64_t(group) * kWidth + column);
        low = __floats2half2_rn(fmaxf(p01.x + q.x, 0.f), fmaxf(p01.y + q.y, 0.f));
        high = __floats2half2_rn(fmaxf(p23.x + q.z, 0.f), fmaxf(p23.y + q.w, 0.f));
      }
      *reinterpret_cast<__half2*>(input + r * kInputStride + column) = low;
      *reinterpret_cast<__half2*>(input + r * kInputStride + column + 2) = high;
    }
    __syncwarp();

    wmma::fragment<wmma::accumulator, kTile, kTile, kTile, float> product[kTilesAcross];
#pragma unroll
    for (int n = 0; n < kTilesAcross; ++n) wmma::fill_fragment(product[n], 0.f);
#pragma unroll
    for (int k = 0; k < kTilesAcross; ++k) {
      wmma::fragment<wmma::matrix_a, kTile, kTile, kTile, __half, wmma::row_major> lhs;
      wmma::load_matrix_sync(lhs, input + k * kTile, kInputStride);
#pragma unroll
      for (int n = 0; n < kTilesAcross; ++n) {
        // Column-major (in, out) view of the row-major (out, in) weight: the hidden layer is input x weight^T.
        wmma::fragment<wmma::matrix_b, kTile, kTile, kTile, __half, wmma::col_major> rhs;
        wmma::load_matrix_sync(rhs, weight + n * kTile * kWeightStride + k * kTile, kWeightStride);
        wmma::mma_sync(product[n], lhs, rhs, product[n]);
      }
    }
    __syncwarp();  // every lane has read the input before the hidden layer overwrites it
#pragma unroll
    for (int n = 0; n < kTilesAcross; ++n)
      wmma::store_matrix_sync(hidden + n * kTile, product[n], kHiddenStride, wmma::mem_row_major);
    __syncwarp();

    // Output layer: two lanes per row, each over half the hidden units, starting at staggered columns so the lanes
    // of a warp read different banks.
    const int r = lane / 2, half = lane % 2;
    float sums[kFusedMaxOutputs];
#pragma unroll
    for (int o = 0; o < kFusedMaxOutputs; ++o) sums[o] = 0.f;
    for (int j = 0; j < kWidth / 2; ++j) {
      const int c = half * (kWidth / 2) + ((j + lane) & (kWidth / 2 - 1));
      const float h = fmaxf(hidden[r * kHiddenStride + c] + hidden_bias[c], 0.f);
#pragma unroll
      for (int o = 0; o < kFusedMaxOutputs; ++o)
        if (o < a.outputs) sums[o] = fmaf(h, output_weight[o * kWidth + c], sums[o]);
    }
    const int64_t row = first_row + r;
    const bool valid = row < a.rows && a.groups[row] >= 0 && a.groups[row] < a.group_count;
#pragma unroll
    for (int o = 0; o < kFusedMaxOutputs; ++o) {
      const float total = sums[o] + __shfl_xor_sync(0xffffffffu, sums[o], 1);
      if (o < a.outputs && half == 0 && row < a.rows)
        a.out[row * a.outputs + o] = valid ? total + output_bias[o] : __int_as_float(0x7fc00000);  // NaN
    }
    __syncwarp();  // the next pass overwrites this one's hidden layer
  }
}

void check(cudaError_t status, const char* what) {
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs gathered MLP: ") + what + " failed: " + cudaGetErrorString(status));
}

}  // namespace

void gathered_mlp_forward(const GatheredMlpArrays& a, cudaStream_t stream) {
  if (a.rows == 0) return;
  int device = 0, processors = 0, blocks_per_processor = 0;
  check(cudaGetDevice(&device), "cudaGetDevice");
  check(cudaDeviceGetAttribute(&processors, cudaDevAttrMultiProcessorCount, device), "cudaDeviceGetAttribute");
  check(cudaFuncSetAttribute(gathered_mlp_kernel, cudaFuncAttributeMaxDynamicSharedMemorySize, kSharedBytes),
        "cudaFuncSetAttribute");
  check(
      cudaOccupancyMaxActiveBlocksPerMultiprocessor(&blocks_per_processor, gathered_mlp_kernel, kThreads, kSharedBytes),
      "cudaOccupancyMaxActiveBlocksPerMultiprocessor");
  const int64_t passes = (a.rows + kTile - 1) / kTile;
  const int64_t wanted = (passes + kWarps - 1) / kWarps;
  const int blocks = int(std::max<int64_t>(1, std::min<int64_t>(wanted, int64_t(processors) * blocks_per_processor)));
  gathered_mlp_kernel<<<blocks, kThreads, kSharedBytes, stream>>>(a);
  check(cudaGetLastError(), "gathered_mlp_kernel launch");
}

}  // namespace sfgs::gathered_mlp::cuda_kernels
