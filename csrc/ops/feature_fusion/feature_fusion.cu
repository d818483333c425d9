// The feature-fusion kernels. Both ops are memory-bound passes over (N, C) rows: the mix reads three arrays and
// writes one (backward: four and three), the merge moves each row once. float arrays go four values a load (float4)
// when their addresses and lengths allow, which keeps more bytes in flight per thread.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "ops/feature_fusion/feature_fusion_kernels.h"
#include "cuda/launch_geometry.cuh"

namespace sfgs::feature_fusion::cuda_kernels {
namespace {

constexpr int kThreads = 256;
constexpr int kBlocksPerSm = 8;   // 2,048 resident threads a multiprocessor (grid-stride beyond)
constexpr int kRowsPerBlock = 8;  // the gather: a warp per row, kRowsPerBlock rows a block at a time
constexpr int kTile = 32;         // the strided gather's square tiles (a warp's lanes along one side)

using cuda_launch::aligned16;

void check_launch(const char* kernel) { cuda_launch::check_launch("feature_fusion", kernel); }

unsigned blocks_for(int64_t work, int64_t work_per_block, int device) {
  return unsigned(cuda_launch::grid_stride_blocks(work, work_per_block, kBlocksPerSm, device, "feature_fusion"));
}

// A float4's four values through the scalar math.
template <typename F> __device__ __forceinline__ float4 each(const float4& x, const float4& y, const float4& z, F f) {
  return make_float4(f(x.x, y.x, z.x), f(x.y, y.y, z.y), f(x.z, y.z, z.z), f(x.w, y.w, z.w));
}

template <typename T> __global__ void __launch_bounds__(kThreads) mix_kernel(const GatedMixArrays<T> a) {
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < a.count; i += int64_t(gridDim.x) * blockDim.x)
    a.out[i] = gated_mix_value(a.logits[i], a.a[i], a.b[i]);
}

__global__ void __launch_bounds__(kThreads) mix_kernel4(const GatedMixArrays<float> a) {
  const auto* logits = reinterpret_cast<const float4*>(a.logits);
  const auto* x = reinterpret_cast<const float4*>(a.a);
  const auto* y = reinterpret_cast<const float4*>(a.b);
  auto* out = reinterpret_cast<float4*>(a.out);
  const int64_t count = a.count / 4;
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < count; i += int64_t(gridDim.x) * blockDim.x)
    out[i] = each(logits[i], x[i], y[i], [](float l, float p, float q) { return gated_mix_value(l, p, q); });
}

template <typename T> __device__ __forceinline__ void mix_gradient_at(const GatedMixGradientArrays<T>& a, int64_t i) {
  const GatedMixGradient<T> g = gated_mix_gradient(a.logits[i], a.a[i], a.b[i], a.grad_out[i]);
  a.grad_logits[i] = g.logit;
  a.grad_a[i] = g.a;
  a.grad_b[i] = g.b;
}

template <typename T>
__global__ void __launch_bounds__(kThreads) mix_backward_kernel(const GatedMixGradientArrays<T> a) {
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < a.count; i += int64_t(gridDim.x) * blockDim.x)
    mix_gradient_at(a, i);
}

__global__ void __launch_bounds__(kThreads) mix_backward_kernel4(const GatedMixGradientArrays<float> a) {
  const int64_t count = a.count / 4;
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < count; i += int64_t(gridDim.x) * blockDim.x) {
    const float4 l = reinterpret_cast<const float4*>(a.logits)[i], x = reinterpret_cast<const float4*>(a.a)[i],
                 y = reinterpret_cast<const float4*>(a.b)[i], g = reinterpret_cast<const float4*>(a.grad_out)[i];
    const GatedMixGradient<float> r[4] = {
        gated_mix_gradient(l.x, x.x, y.x, g.x), gated_mix_gradient(l.y, x.y, y.y, g.y),
        gated_mix_gradient(l.z, x.z, y.z, g.z), gated_mix_gradient(l.w, x.w, y.w, g.w)};
    reinterpret_cast<float4*>(a.grad_logits)[i] = make_float4(r[0].logit, r[1].logit, r[2].logit, r[3].logit);
    reinterpret_cast<float4*>(a.grad_a)[i] = make_float4(r[0].a, r[1].a, r[2].a, r[3].a);
    reinterpret_cast<float4*>(a.grad_b)[i] = make_float4(r[0].b, r[1].b, r[2].b, r[3].b);
  }
}

template <typename V> __device__ V not_a_number() { return V(NAN); }
template <> __device__ float4 not_a_number<float4>() { return make_float4(NAN, NAN, NAN, NAN); }

// A warp per row (threadIdx.y), its lanes over the row's `vectors` values of V (T, or float4 for float rows of a
// multiple of four): for sources whose rows are contiguous.
template <typename V, typename T>
__global__ void __launch_bounds__(32 * kRowsPerBlock) gather_kernel(const RowGatherArrays<T> r, int64_t vectors) {
  for (int64_t row = int64_t(blockIdx.x) * blockDim.y + threadIdx.y; row < r.rows;
       row += int64_t(gridDim.x) * blockDim.y) {
    const V* from = reinterpret_cast<const V*>(gather_source_row(r, row).values);
    V* to = reinterpret_cast<V*>(gather_destination_row(r, row));
    for (int64_t c = threadIdx.x; c < vectors; c += 32) to[c] = from != nullptr ? from[c] : not_a_number<V>();
  }
}

// Tiles of kTile rows x kTile columns through shared memory, for strided sources: the tile is read with the lanes
// along the rows when `lanes_over_rows` (a transposed source, whose columns are contiguous: the planes' samples),
// else along the columns, and written with the lanes along the columns (contiguous destination rows).
template <typename T>
__global__ void __launch_bounds__(32 * kRowsPerBlock)
    tiled_gather_kernel(const RowGatherArrays<T> r, bool lanes_over_rows) {
  __shared__ T tile[kTile][kTile + 1];  // +1: the transposed accesses hit distinct banks
  const int64_t column_tiles = (r.columns + kTile - 1) / kTile, tiles = (r.rows + kTile - 1) / kTile * column_tiles;
  for (int64_t t = blockIdx.x; t < tiles; t += gridDim.x) {
    const int64_t row0 = t / column_tiles * kTile, column0 = t % column_tiles * kTile;
    for (int k = threadIdx.y; k < kTile; k += blockDim.y) {
      const int i = lanes_over_rows ? threadIdx.x : k, j = lanes_over_rows ? k : threadIdx.x;
      if (row0 + i < r.rows && column0 + j < r.columns) {
        const SourceRow<T> from = gather_source_row(r, row0 + i);
        tile[i][j] = from.values != nullptr ? from.values[(column0 + j) * from.column_stride] : not_a_number<T>();
      }
    }
    __syncthreads();
    for (int k = threadIdx.y; k < kTile; k += blockDim.y)
      if (row0 + k < r.rows && column0 + threadIdx.x < r.columns)
        gather_destination_row(r, row0 + k)[column0 + threadIdx.x] = tile[k][threadIdx.x];
    __syncthreads();
  }
}

template <typename T> bool vectorisable(const GatedMixArrays<T>&) { return false; }
bool vectorisable(const GatedMixArrays<float>& a) {
  return a.count % 4 == 0 && aligned16(a.logits) && aligned16(a.a) && aligned16(a.b) && aligned16(a.out);
}
template <typename T> bool vectorisable(const GatedMixGradientArrays<T>&) { return false; }
bool vectorisable(const GatedMixGradientArrays<float>& a) {
  return a.count % 4 == 0 && aligned16(a.logits) && aligned16(a.a) && aligned16(a.b) && aligned16(a.grad_out) &&
         aligned16(a.grad_logits) && aligned16(a.grad_a) && aligned16(a.grad_b);
}
template <typename T> bool vectorisable(const RowGatherArrays<T>&) { return false; }
bool vectorisable(const RowGatherArrays<float>& r) {
  // Row strides of a multiple of four floats keep every row's start 16-byte aligned when the arrays' starts are.
  return r.columns % 4 == 0 && r.first_row_stride % 4 == 0 && r.second_row_stride % 4 == 0 && aligned16(r.first) &&
         aligned16(r.second) && aligned16(r.out_first) && aligned16(r.out_second);
}

// Whether both sources' rows are contiguous (column stride 1; an absent or empty second source counts as such).
template <typename T> bool contiguous_source_rows(const RowGatherArrays<T>& r) {
  const bool second_absent = r.second == nullptr || r.rows <= r.first_rows;
  return (r.first_column_stride == 1 || r.first_rows == 0) && (r.second_column_stride == 1 || second_absent);
}

}  // namespace

template <typename T> void gated_mix(const GatedMixArrays<T>& a, int device, cudaStream_t stream) {
  if (a.count == 0) return;
  if constexpr (std::is_same_v<T, float>) {
    if (vectorisable(a)) {
      mix_kernel4<<<blocks_for(a.count / 4, kThreads, device), kThreads, 0, stream>>>(a);
      return check_launch("mix_kernel4");
    }
  }
  mix_kernel<T><<<blocks_for(a.count, kThreads, device), kThreads, 0, stream>>>(a);
  check_launch("mix_kernel");
}

template <typename T> void gated_mix_backward(const GatedMixGradientArrays<T>& a, int device, cudaStream_t stream) {
  if (a.count == 0) return;
  if constexpr (std::is_same_v<T, float>) {
    if (vectorisable(a)) {
      mix_backward_kernel4<<<blocks_for(a.count / 4, kThreads, device), kThreads, 0, stream>>>(a);
      return check_launch("mix_backward_kernel4");
    }
  }
  mix_backward_kernel<T><<<blocks_for(a.count, kThreads, device), kThreads, 0, stream>>>(a);
  check_launch("mix_backward_kernel");
}

template <typename T> void gather_rows(const RowGatherArrays<T>& r, int device, cudaStream_t stream) {
  if (r.rows == 0 || r.columns == 0) return;
  const dim3 block(32, kRowsPerBlock);
  if (!contiguous_source_rows(r)) {
    const int64_t tiles = (r.rows + kTile - 1) / kTile * ((r.columns + kTile - 1) / kTile);
    tiled_gather_kernel<T><<<blocks_for(tiles, 1, device), block, 0, stream>>>(r, r.first_row_stride == 1);
    return check_launch("tiled_gather_kernel");
  }
  const unsigned blocks = blocks_for(r.rows, kRowsPerBlock, device);
  if constexpr (std::is_same_v<T, float>) {
    if (vectorisable(r)) {
      gather_kernel<float4, float><<<blocks, block, 0, stream>>>(r, r.columns / 4);
      return check_launch("gather_kernel (float4)");
    }
  }
  gather_kernel<T, T><<<blocks, block, 0, stream>>>(r, r.columns);
  check_launch("gather_kernel");
}

template void gated_mix<float>(const GatedMixArrays<float>&, int, cudaStream_t);
template void gated_mix<double>(const GatedMixArrays<double>&, int, cudaStream_t);
template void gated_mix_backward<float>(const GatedMixGradientArrays<float>&, int, cudaStream_t);
template void gated_mix_backward<double>(const GatedMixGradientArrays<double>&, int, cudaStream_t);
template void gather_rows<float>(const RowGatherArrays<float>&, int, cudaStream_t);
template void gather_rows<double>(const RowGatherArrays<double>&, int, cudaStream_t);

}  // namespace sfgs::feature_fusion::cuda_kernels
