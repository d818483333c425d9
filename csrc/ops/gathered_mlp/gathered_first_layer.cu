// The gathered first layer's kernels (gathered_first_layer_kernels.h): memory-bound walks over the (N, H) rows, a
// warp a row (grid-stride) with its lanes over the columns, the G group rows staying in cache. The forward reads
// float rows four values a load (float4) where the width and the addresses allow.
// The backward writes each row's gradient and adds it into its block's table of the groups' sums (G x H) in shared
// memory, so the groups' gradient takes no global atomic adds (216k rows onto 55 joints would queue on a few
// addresses); a warp's lanes take consecutive columns, so their shared adds hit distinct banks and never one address.
// Each block writes its table as one partial row, which the op sums in a fixed order (linear::column_sum); within a
// block the warps' adds land in the order they come (the last bits may differ between runs). A table
// over 48 KiB (double at H = 128, G = 55: 55 KiB) opts in to the device's larger dynamic shared memory
// (cudaFuncSetAttribute: a setting of the kernel, not a stream operation, so CUDA graph capture goes on); a table
// beyond even that (hundreds of groups) is the block's partial row itself, in global memory, which only the block's
// own warps add into.
#include <algorithm>
#include <cstdint>
#include <type_traits>

#include "ops/gathered_mlp/gathered_first_layer_kernels.h"
#include "cuda/launch_geometry.cuh"

namespace sfgs::gathered_mlp::cuda_kernels {
namespace {

constexpr int kWarpSize = 32;
constexpr int kForwardWarps = 8;                   // a forward block's warps, a row each at a time
constexpr int kForwardBlocksPerSm = 8;             // 2,048 resident threads a multiprocessor (grid-stride beyond)
constexpr int kBackwardWarps = 32;                 // 1,024 threads share a block's table
constexpr int kBackwardBlocksPerSm = 2;            // both resident on sm_90 (2,048 threads); few partial tables to sum
constexpr int kColumnSlabs = 4;                    // a backward lane's loads in flight: this many slabs of 32 columns
constexpr size_t kDefaultSharedBytes = 48 * 1024;  // dynamic shared memory a block gets without opting in
constexpr int kForwardThreads = kWarpSize * kForwardWarps;
constexpr int kBackwardThreads = kWarpSize * kBackwardWarps;

constexpr const char* kOwner = "gathered_first_layer";
using cuda_launch::aligned16;

void check_launch(const char* kernel) { cuda_launch::check_launch(kOwner, kernel); }

int64_t blocks_for(int64_t rows, int rows_per_block, int blocks_per_sm, int device) {
  return cuda_launch::grid_stride_blocks(rows, rows_per_block, blocks_per_sm, device, kOwner);
}

// The forward's values of one load: a T, or four floats.
template <typename T> __device__ __forceinline__ T forward_value(T row_input, T group_input) {
  return first_layer_value(row_input, group_input);
}

__device__ __forceinline__ float4 forward_value(const float4& row_input, const float4& group_input) {
  return make_float4(first_layer_value(row_input.x, group_input.x), first_layer_value(row_input.y, group_input.y),
                     first_layer_value(row_input.z, group_input.z), first_layer_value(row_input.w, group_input.w));
}

template <typename V> __device__ __forceinline__ V invalid_value() { return invalid_group_value<V>(); }

template <> __device__ __forceinline__ float4 invalid_value<float4>() {
  const float nan = invalid_group_value<float>();
  return make_float4(nan, nan, nan, nan);
}

// A warp per row (threadIdx.y), its lanes over the row's `vectors` values of V (T, or float4 for float rows of a
// multiple of four).
template <typename V, typename T>
__global__ void __launch_bounds__(kForwardThreads) forward_kernel(const FirstLayerArrays<T> a, int64_t vectors) {
  const V* row_inputs = reinterpret_cast<const V*>(a.row_inputs);
  const V* group_inputs = reinterpret_cast<const V*>(a.group_inputs);
  V* out = reinterpret_cast<V*>(a.out);
  for (int64_t row = int64_t(blockIdx.x) * kForwardWarps + threadIdx.y; row < a.rows;
       row += int64_t(gridDim.x) * kForwardWarps) {
    const int64_t group = a.groups[row];
    const V* group_row = valid_group(group, a.group_count) ? group_inputs + group * vectors : nullptr;
    for (int64_t v = threadIdx.x; v < vectors; v += kWarpSize)
      out[row * vectors + v] =
          group_row ? forward_value(row_inputs[row * vectors + v], group_row[v]) : invalid_value<V>();
  }
}

// A warp per row (threadIdx.y), lane l on columns l, l + 32, ...: each pass loads kColumnSlabs slabs of the row's
// out and grad_out before it stores any gradient. The block's table is shared memory (kSharedTable) or its own
// partial row.
template <typename T, bool kSharedTable>
__global__ void __launch_bounds__(kBackwardThreads) backward_kernel(const FirstLayerGradientArrays<T> a) {
  extern __shared__ __align__(16) unsigned char shared_bytes[];
  const int64_t table_size = a.group_count * a.width;
  T* partial = a.group_partials + int64_t(blockIdx.x) * table_size;
  T* table = kSharedTable ? reinterpret_cast<T*>(shared_bytes) : partial;
  const int thread = threadIdx.y * kWarpSize + threadIdx.x;
  for (int64_t i = thread; i < table_size; i += kBackwardThreads) table[i] = T(0);
  __syncthreads();

  for (int64_t row = int64_t(blockIdx.x) * kBackwardWarps + threadIdx.y; row < a.rows;
       row += int64_t(gridDim.x) * kBackwardWarps) {
    const int64_t group = a.groups[row];
    T* sums = valid_group(group, a.group_count) ? table + group * a.width : nullptr;
    const int64_t first = row * a.width;
    for (int64_t base = threadIdx.x; base < a.width; base += kColumnSlabs * kWarpSize) {
      T out[kColumnSlabs], grad_out[kColumnSlabs];
#pragma unroll
      for (int k = 0; k < kColumnSlabs; ++k) {
        const int64_t column = base + k * kWarpSize;
        out[k] = column < a.width ? a.out[first + column] : T(0);
        grad_out[k] = column < a.width ? a.grad_out[first + column] : T(0);
      }
#pragma unroll
      for (int k = 0; k < kColumnSlabs; ++k) {
        const int64_t column = base + k * kWarpSize;
        if (column >= a.width) break;
        const T grad = first_layer_gradient(out[k], grad_out[k]);
        a.grad_rows[first + column] = grad;
        if (sums) atomicAdd(sums + column, grad);
      }
    }
  }

  if constexpr (kSharedTable) {
    __syncthreads();
    for (int64_t i = thread; i < table_size; i += kBackwardThreads) partial[i] = table[i];
  }
}

template <typename T> bool vectorisable(const FirstLayerArrays<T>&) { return false; }
bool vectorisable(const FirstLayerArrays<float>& a) {
  // Rows of a multiple of four floats keep every row's start 16-byte aligned when the arrays' starts are.
  return a.width % 4 == 0 && aligned16(a.row_inputs) && aligned16(a.group_inputs) && aligned16(a.out);
}

}  // namespace

int64_t first_layer_backward_blocks(int64_t rows, int device) {
  return blocks_for(rows, kBackwardWarps, kBackwardBlocksPerSm, device);
}

template <typename T> void first_layer_forward(const FirstLayerArrays<T>& a, int device, cudaStream_t stream) {
  const dim3 block(kWarpSize, kForwardWarps);
  const unsigned blocks = unsigned(blocks_for(a.rows, kForwardWarps, kForwardBlocksPerSm, device));
  if constexpr (std::is_same_v<T, float>) {
    if (vectorisable(a)) {
      forward_kernel<float4, float><<<blocks, block, 0, stream>>>(a, a.width / 4);
      return check_launch("forward_kernel (float4)");
    }
  }
  forward_kernel<T, T><<<blocks, block, 0, stream>>>(a, a.width);
  check_launch("forward_kernel");
}

template <typename T> void first_layer_backward(const FirstLayerGradientArrays<T>& a, int device, cudaStream_t stream) {
  const size_t table_bytes = size_t(a.group_count * a.width) * sizeof(T);
  const dim3 block(kWarpSize, kBackwardWarps);
  const unsigned blocks = unsigned(a.partial_rows);
  const size_t shared_limit = size_t(cuda_launch::device_attribute(cudaDevAttrMaxSharedMemoryPerBlockOptin, device,
                                                                   kOwner, "shared memory a block may opt in to"));
  if (table_bytes > shared_limit) {
    backward_kernel<T, false><<<blocks, block, 0, stream>>>(a);
    return check_launch("backward_kernel (global table)");
  }
  if (table_bytes > kDefaultSharedBytes)
    cuda_launch::check(
        cudaFuncSetAttribute(backward_kernel<T, true>, cudaFuncAttributeMaxDynamicSharedMemorySize, int(table_bytes)),
        kOwner, "opting in to the backward's shared table");
  backward_kernel<T, true><<<blocks, block, table_bytes, stream>>>(a);
  check_launch("backward_kernel (shared table)");
}

template void first_layer_forward<float>(const FirstLayerArrays<float>&, int, cudaStream_t);
template void first_layer_forward<double>(const FirstLayerArrays<double>&, int, cudaStream_t);
template void first_layer_backward<float>(const FirstLayerGradientArrays<float>&, int, cudaStream_t);
template void first_layer_backward<double>(const FirstLayerGradientArrays<double>&, int, cudaStream_t);

}  // namespace sfgs::gathered_mlp::cuda_kernels
