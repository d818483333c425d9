// The fused MLP inference kernel (mlp_inference_kernels.h). A warp takes 16 rows at a time and keeps their
// activations in registers from the input to the output: each layer is mma.sync m16n8k16 (half operands, float
// accumulation), whose accumulator layout for two neighbouring 8-column tiles is exactly the operand layout of one
// 16-column tile of the next layer's input, so a layer's output feeds the next without a trip through memory. A
// GroupNorm group (32 columns, four tiles) lies in the four lanes that share a row, so its moments are two shuffles.
// The block converts the hidden layers' weights to half once into shared memory, with the biases and GroupNorm's
// parameters beside them; a weight row is padded by four words, so the eight rows one ldmatrix phase reads fall in
// different banks, and every operand address is a per-lane base plus a constant.
#include <cuda_fp16.h>

#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "ops/mlp_inference/mlp_inference_kernels.h"

namespace sfgs::mlp_inference::cuda_kernels {
namespace {

constexpr int kWidth = kFusedWidth;
constexpr int kRowsPerPass = 16;                          // the mma tile's rows
constexpr int kTilesAcross = kWidth / 16;                 // 16-column input tiles of a layer
constexpr int kOutputTiles = kWidth / 8;                  // 8-column output tiles of a layer
constexpr int kGroupTiles = kOutputTiles / kFusedGroups;  // output tiles per GroupNorm group
constexpr int kRowPadWords = 4;                           // a row's padding: 16 bytes, one ldmatrix row
constexpr int kHiddenStride = kWidth / 2 + kRowPadWords;  // words (half pairs) per hidden weight row
constexpr int kHiddenLayerWords = kWidth * kHiddenStride;
constexpr int kParameterFloats = 3 * kWidth;  // a layer's bias, gamma and beta
constexpr int kWarps = 8;
constexpr int kThreads = kWarps * 32;
static_assert(kGroupTiles == 4 && kFusedGroups * kGroupTiles * 8 == kWidth,
              "a group is four 8-column tiles: two 16-column input tiles of the next layer");
static_assert(kFusedMaxInputWidth <= kWidth, "the first layer's input is at most one layer wide");

// Words per first-layer weight row for `tiles` 16-column input tiles: 8 a tile and the padding, which keeps the
// stride an odd multiple of 4 words (16 bytes): eight consecutive rows start in eight different bank groups.
__host__ __device__ constexpr int first_stride(int tiles) { return 8 * tiles + kRowPadWords; }

__host__ __device__ int input_tiles_of(const MlpInferenceArrays& a) {
  int width = 0;
  for (int b = 0; b < a.input_count; ++b) width += a.inputs[b].width;
  return (width + 15) / 16;
}

// Shared memory, in 4-byte words: the first layer, the hidden layers after it, then each layer's parameters.
int shared_words(int hidden_layers, int input_tiles) {
  return kWidth * first_stride(input_tiles) + (hidden_layers - 1) * kHiddenLayerWords +
         hidden_layers * kParameterFloats;
}

__device__ __forceinline__ uint32_t pack(float low, float high) {
  const __half2 h = __floats2half2_rn(low, high);
  return *reinterpret_cast<const uint32_t*>(&h);
}

// Half keeps 11 significant bits (as TF32) but a narrower range: inputs beyond it saturate rather than become inf
// (a NaN stays NaN: both comparisons are false).
__device__ __forceinline__ float in_half_range(float x) {
  constexpr float kHalfMax = 65504.f;
  return x > kHalfMax ? kHalfMax : (x < -kHalfMax ? -kHalfMax : x);
}

// ReLU that keeps a NaN (fmaxf would turn it into 0), as the reference's at::relu does.
__device__ __forceinline__ float relu(float v) { return v < 0.f ? 0.f : v; }

__device__ __forceinline__ void mma(float (&d)[4], const uint32_t (&a)[4], uint32_t b0, uint32_t b1) {
  // Not volatile: a product reads registers only, so the compiler may interleave it with the next operand loads.
  asm("mma.sync.aligned.m16n8k16.row.col.f32.f16.f16.f32 {%0,%1,%2,%3}, {%4,%5,%6,%7}, {%8,%9}, {%0,%1,%2,%3};\n"
      : "+f"(d[0]), "+f"(d[1]), "+f"(d[2]), "+f"(d[3])
      : "r"(a[0]), "r"(a[1]), "r"(a[2]), "r"(a[3]), "r"(b0), "r"(b1));
}

__device__ __forceinline__ float quad_sum(float v) {
  v += __shfl_xor_sync(0xffffffffu, v, 1);
  return v + __shfl_xor_sync(0xffffffffu, v, 2);
}

// `read(block, column in it)` for column `column` of the first layer's (logically concatenated) input blocks; a zero
// value past the last column. The loop over the blocks is unrolled, so every block is reached by a constant index
// (the parameter space is never indexed at run time).
template <typename Read>
__device__ __forceinline__ auto at_column(const MlpInferenceArrays& a, int column, Read read)
    -> decltype(read(a.inputs[0], 0)) {
#pragma unroll
  for (int b = 0; b < kFusedMaxInputs; ++b) {
    if (b >= a.input_count) break;
    if (column < a.inputs[b].width) return read(a.inputs[b], column);
    column -= a.inputs[b].width;
  }
  return {};
}

// Columns `column` and `column` + 1 (even) of the first layer's input for `row` as the half pair of an mma operand;
// 0 past the last row or column. Blocks of even widths and strides read the pair at once.
__device__ __forceinline__ uint32_t input_pair(const MlpInferenceArrays& a, int64_t row, int column) {
  if (row >= a.rows) return 0u;
  if (a.paired_inputs)
    return at_column(a, column, [row](const InputBlock& block, int c) {
      const float2 p = *reinterpret_cast<const float2*>(block.values + row * block.values_stride + c);
      return pack(in_half_range(p.x), in_half_range(p.y));
    });
  const auto value = [row](const InputBlock& block, int c) { return block.values[row * block.values_stride + c]; };
  return pack(in_half_range(at_column(a, column, value)), in_half_range(at_column(a, column + 1, value)));
}

// Column `column` of the first layer's weight row `row`; 0 past the inputs' columns.
__device__ __forceinline__ float first_weight_at(const MlpInferenceArrays& a, int row, int column) {
  return at_column(a, column,
                   [row](const InputBlock& block, int c) { return block.weight[row * block.weight_stride + c]; });
}

// The B operands of two neighbouring 8-column output tiles for one 16-column input tile: four 8x8 half matrices,
// lane i giving the address of row i % 8 of matrix i / 8 (`address`: shared-space bytes).
__device__ __forceinline__ void load_operands(uint32_t address, uint32_t (&b)[4]) {
  asm volatile("ldmatrix.sync.aligned.m8n8.x4.shared.b16 {%0,%1,%2,%3}, [%4];\n"
               : "=r"(b[0]), "=r"(b[1]), "=r"(b[2]), "=r"(b[3])
               : "r"(address));
}

// acc += input tile t (x) times the layer's weight, whose rows lie `stride` words apart from the lane's ldmatrix
// address `base`: every output tile, two a load.
__device__ __forceinline__ void multiply_tile(float (&acc)[kOutputTiles][4], const uint32_t (&x)[4], uint32_t base,
                                              int stride, int t) {
#pragma unroll
  for (int n = 0; n < kOutputTiles; n += 2) {
    uint32_t b[4];
    load_operands(base + 4 * (n * 8 * stride + 8 * t), b);
    mma(acc[n], x, b[0], b[1]);
    mma(acc[n + 1], x, b[2], b[3]);
  }
}

// GroupNorm of a layer's accumulators over each group's 32 columns of a row (eight values in each of the row's four
// lanes), the affine map and the ReLU, packed as the next layer's input: output tile 2t + e is half e of input
// tile t.
__device__ __forceinline__ void group_norm_relu(const float (&acc)[kOutputTiles][4], const float* gamma,
                                                const float* beta, float epsilon, int quad_column,
                                                uint32_t (&x)[kTilesAcross][4]) {
  constexpr float kInverseGroupSize = 1.f / (kGroupTiles * 8);
  float mean[kFusedGroups][2], scale[kFusedGroups][2];
#pragma unroll
  for (int g = 0; g < kFusedGroups; ++g) {
    float low = 0.f, high = 0.f;
#pragma unroll
    for (int j = 0; j < kGroupTiles; ++j) {
      low += acc[g * kGroupTiles + j][0] + acc[g * kGroupTiles + j][1];
      high += acc[g * kGroupTiles + j][2] + acc[g * kGroupTiles + j][3];
    }
    mean[g][0] = quad_sum(low) * kInverseGroupSize;
    mean[g][1] = quad_sum(high) * kInverseGroupSize;
  }
#pragma unroll
  for (int g = 0; g < kFusedGroups; ++g) {
    float low = 0.f, high = 0.f;
#pragma unroll
    for (int j = 0; j < kGroupTiles; ++j) {
      const float* v = acc[g * kGroupTiles + j];
      low += (v[0] - mean[g][0]) * (v[0] - mean[g][0]) + (v[1] - mean[g][0]) * (v[1] - mean[g][0]);
      high += (v[2] - mean[g][1]) * (v[2] - mean[g][1]) + (v[3] - mean[g][1]) * (v[3] - mean[g][1]);
    }
    scale[g][0] = rsqrtf(quad_sum(low) * kInverseGroupSize + epsilon);
    scale[g][1] = rsqrtf(quad_sum(high) * kInverseGroupSize + epsilon);
  }
#pragma unroll
  for (int n = 0; n < kOutputTiles; ++n) {
    const int g = n / kGroupTiles, c = n * 8 + quad_column;
    const float2 k = *reinterpret_cast<const float2*>(gamma + c);
    const float2 m = *reinterpret_cast<const float2*>(beta + c);
    const float l0 = relu(fmaf((acc[n][0] - mean[g][0]) * scale[g][0], k.x, m.x));
    const float l1 = relu(fmaf((acc[n][1] - mean[g][0]) * scale[g][0], k.y, m.y));
    const float h0 = relu(fmaf((acc[n][2] - mean[g][1]) * scale[g][1], k.x, m.x));
    const float h1 = relu(fmaf((acc[n][3] - mean[g][1]) * scale[g][1], k.y, m.y));
    x[n / 2][2 * (n % 2)] = pack(l0, l1);
    x[n / 2][2 * (n % 2) + 1] = pack(h0, h1);
  }
}

__global__ void __launch_bounds__(kThreads, 2) mlp_inference_kernel(const MlpInferenceArrays a) {
  extern __shared__ __align__(16) uint32_t shared[];
  const int input_tiles = input_tiles_of(a);
  const int stride0 = first_stride(input_tiles);
  uint32_t* first_weights = shared;
  uint32_t* hidden_weights = shared + kWidth * stride0;  // layer k >= 1 at (k - 1) * kHiddenLayerWords
  float* parameters = reinterpret_cast<float*>(hidden_weights + (a.hidden_layers - 1) * kHiddenLayerWords);
  for (int i = threadIdx.x; i < kWidth * 8 * input_tiles; i += kThreads) {
    const int row = i / (8 * input_tiles), word = i % (8 * input_tiles);
    first_weights[row * stride0 + word] =
        pack(first_weight_at(a, row, 2 * word), first_weight_at(a, row, 2 * word + 1));
  }
  for (int layer = 1; layer < a.hidden_layers; ++layer) {
    const float2* w = reinterpret_cast<const float2*>(a.hidden_weights[layer - 1]);
    for (int i = threadIdx.x; i < kWidth * kWidth / 2; i += kThreads) {
      const float2 pair = w[i];
      hidden_weights[(layer - 1) * kHiddenLayerWords + (i / (kWidth / 2)) * kHiddenStride + i % (kWidth / 2)] =
          pack(pair.x, pair.y);
    }
  }
  for (int i = threadIdx.x; i < a.hidden_layers * kWidth; i += kThreads) {
    const int layer = i / kWidth, c = i % kWidth;
    float* p = parameters + layer * kParameterFloats;
    p[c] = layer == 0 ? a.first_bias[c] : a.hidden_biases[layer - 1][c];
    p[kWidth + c] = a.norm_weights[layer][c];
    p[2 * kWidth + c] = a.norm_biases[layer][c];
  }
  __syncthreads();

  const int warp = threadIdx.x / 32, lane = threadIdx.x % 32;
  const int quad_row = lane / 4, quad_column = (lane % 4) * 2;  // the fragments' row and column within a tile
  // The row this lane addresses for ldmatrix (matrix lane / 8: output tile + (lane / 16), input half (lane / 8) % 2)
  // in words from a layer's start, for output tiles 0 and 1 of input tile 0.
  const int matrix_row = (lane / 16) * 8 + lane % 8, matrix_half = ((lane / 8) % 2) * 4;
  const uint32_t first_base = uint32_t(__cvta_generic_to_shared(first_weights + matrix_row * stride0 + matrix_half));
  const uint32_t hidden_base =
      uint32_t(__cvta_generic_to_shared(hidden_weights + matrix_row * kHiddenStride + matrix_half));
  const int64_t passes = (a.rows + kRowsPerPass - 1) / kRowsPerPass;
  for (int64_t pass = int64_t(blockIdx.x) * kWarps + warp; pass < passes; pass += int64_t(gridDim.x) * kWarps) {
    const int64_t low_row = pass * kRowsPerPass + quad_row, high_row = low_row + 8;
    // The layer's input as mma operands: tile t holds columns 16t .. 16t + 15 of the warp's 16 rows.
    uint32_t x[kTilesAcross][4];
#pragma unroll
    for (int t = 0; t < kTilesAcross; ++t) {
      const int c = 16 * t + quad_column;
      const bool used = t < input_tiles;
      x[t][0] = used ? input_pair(a, low_row, c) : 0u;
      x[t][1] = used ? input_pair(a, high_row, c) : 0u;
      x[t][2] = used ? input_pair(a, low_row, c + 8) : 0u;
      x[t][3] = used ? input_pair(a, high_row, c + 8) : 0u;
    }

    for (int layer = 0; layer < a.hidden_layers; ++layer) {
      const float* p = parameters + layer * kParameterFloats;
      // Every output tile at once: sixteen independent accumulations keep the tensor cores busy while each waits
      // on its previous product.
      float acc[kOutputTiles][4];
#pragma unroll
      for (int n = 0; n < kOutputTiles; ++n) {
        const int c = n * 8 + quad_column;
        const float2 b = *reinterpret_cast<const float2*>(p + c);
        acc[n][0] = acc[n][2] = b.x;
        acc[n][1] = acc[n][3] = b.y;
        if (layer == 0 && a.base != nullptr) {
          if (low_row < a.rows) {
            const float2 s = *reinterpret_cast<const float2*>(a.base + low_row * kWidth + c);
            acc[n][0] += s.x;
            acc[n][1] += s.y;
          }
          if (high_row < a.rows) {
            const float2 s = *reinterpret_cast<const float2*>(a.base + high_row * kWidth + c);
            acc[n][2] += s.x;
            acc[n][3] += s.y;
          }
        }
      }
      if (layer == 0) {
#pragma unroll
        for (int t = 0; t < kTilesAcross; ++t) {
          if (t >= input_tiles) break;  // x is indexed by constants only: it stays in registers
          multiply_tile(acc, x[t], first_base, stride0, t);
        }
      } else {
        // A constant stride: every operand address is the lane's base plus an immediate.
        const uint32_t base = hidden_base + 4 * (layer - 1) * kHiddenLayerWords;
#pragma unroll
        for (int t = 0; t < kTilesAcross; ++t) multiply_tile(acc, x[t], base, kHiddenStride, t);
      }
      group_norm_relu(acc, p + kWidth, p + 2 * kWidth, a.epsilon, quad_column, x);
    }

    // The output layer: one 8-column tile, its operands read from global memory (cached) in float.
    float out[4];
    const int c = quad_column;
    out[0] = out[2] = c < a.outputs ? a.output_bias[c] : 0.f;
    out[1] = out[3] = c + 1 < a.outputs ? a.output_bias[c + 1] : 0.f;
    const bool weighted = quad_row < a.outputs;
    const float* w = a.output_weight + quad_row * kWidth + quad_column;
#pragma unroll
    for (int t = 0; t < kTilesAcross; ++t) {
      const float2 low = weighted ? __ldg(reinterpret_cast<const float2*>(w + 16 * t)) : make_float2(0.f, 0.f);
      const float2 high = weighted ? __ldg(reinterpret_cast<const float2*>(w + 16 * t + 8)) : make_float2(0.f, 0.f);
      mma(out, x[t], pack(low.x, low.y), pack(high.x, high.y));
    }
#pragma unroll
    for (int e = 0; e < 2; ++e) {
      if (c + e >= a.outputs) continue;
      if (low_row < a.rows) a.out[low_row * a.outputs + c + e] = out[e];
      if (high_row < a.rows) a.out[high_row * a.outputs + c + e] = out[2 + e];
    }
  }
}

void check(cudaError_t status, const char* what) {
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs MLP inference: ") + what + " failed: " + cudaGetErrorString(status));
}

}  // namespace

int shared_bytes(int hidden_layers, int input_width) {
  return 4 * shared_words(hidden_layers, (input_width + 15) / 16);
}

bool fits(int hidden_layers, int input_width, int device) {
  int most = 0;
  check(cudaDeviceGetAttribute(&most, cudaDevAttrMaxSharedMemoryPerBlockOptin, device), "cudaDeviceGetAttribute");
  return shared_bytes(hidden_layers, input_width) <= most;
}

void forward(const MlpInferenceArrays& a, cudaStream_t stream) {
  if (a.rows == 0) return;
  const int bytes = 4 * shared_words(a.hidden_layers, input_tiles_of(a));
  int device = 0, processors = 0, blocks_per_processor = 0;
  check(cudaGetDevice(&device), "cudaGetDevice");
  check(cudaDeviceGetAttribute(&processors, cudaDevAttrMultiProcessorCount, device), "cudaDeviceGetAttribute");
  // The largest any network may need (within what the device gives), not this one's: a CUDA graph's earlier kernel
  // node of a larger network must still launch after this call.
  int most = 0;
  check(cudaDeviceGetAttribute(&most, cudaDevAttrMaxSharedMemoryPerBlockOptin, device), "cudaDeviceGetAttribute");
  const int largest = std::min(most, shared_bytes(kFusedMaxHiddenLayers, kFusedMaxInputWidth));
  check(cudaFuncSetAttribute(mlp_inference_kernel, cudaFuncAttributeMaxDynamicSharedMemorySize, largest),
        "cudaFuncSetAttribute");
  check(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&blocks_per_processor, mlp_inference_kernel, kThreads, bytes),
        "cudaOccupancyMaxActiveBlocksPerMultiprocessor");
  const int64_t passes = (a.rows + kRowsPerPass - 1) / kRowsPerPass;
  const int64_t wanted = (passes + kWarps - 1) / kWarps;
  const int blocks =
      int(std::max<int64_t>(1, std::min<int64_t>(wanted, int64_t(processors) * std::max(1, blocks_per_processor))));
  mlp_inference_kernel<<<blocks, kThreads, bytes, stream>>>(a);
  check(cudaGetLastError(), "mlp_inference_kernel launch");
}

}  // namespace sfgs::mlp_inference::cuda_kernels
