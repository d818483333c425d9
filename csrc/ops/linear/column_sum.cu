// Column sums of a row-major (R, C) matrix. A block takes 32 columns (a warp's lanes, so each row's read is one
// coalesced segment) and a chunk of rows, its kRowLanes warps striding over the chunk four rows at a time (four
// independent loads in flight a thread); the block's sums meet in shared memory and go to one partial row. A second
// launch sums the partial rows the same way. Fixed order throughout: the same result every run.
#include <algorithm>

#include "ops/linear/column_sum_kernels.h"
#include "cuda/launch_geometry.cuh"

namespace sfgs::linear::cuda_kernels {
namespace {

constexpr int kColumnsPerBlock = 32;   // a warp's lanes: one coalesced read of 32 columns a row
constexpr int kRowLanes = 8;           // warps a block, each over every kRowLanes-th row of the chunk
constexpr int kBlocksPerSm = 8;        // blocks the first pass aims at a multiprocessor
constexpr int64_t kMinChunkRows = 64;  // fewer rows a chunk would cost more in partial rows than it spreads
constexpr int64_t kMaxChunks = 256;    // the second pass's rows: one block sums them in 32 rows a warp

template <typename T>
__global__ void __launch_bounds__(32 * kRowLanes)
    column_sum_kernel(const T* rows, int64_t row_count, int64_t columns, int64_t chunk_rows, T* out) {
  __shared__ T lane_sums[kRowLanes][kColumnsPerBlock + 1];  // +1: the column reads hit distinct banks
  const int64_t column = int64_t(blockIdx.x) * kColumnsPerBlock + threadIdx.x;
  const int64_t begin = int64_t(blockIdx.y) * chunk_rows;
  const int64_t end = begin + chunk_rows < row_count ? begin + chunk_rows : row_count;
  T sum = 0;
  if (column < columns) {
    int64_t row = begin + threadIdx.y;
    for (; row + 3 * kRowLanes < end; row += 4 * kRowLanes) {
      const T a = rows[row * columns + column], b = rows[(row + kRowLanes) * columns + column];
      const T c = rows[(row + 2 * kRowLanes) * columns + column], d = rows[(row + 3 * kRowLanes) * columns + column];
      sum += (a + b) + (c + d);
    }
    for (; row < end; row += kRowLanes) sum += rows[row * columns + column];
  }
  lane_sums[threadIdx.y][threadIdx.x] = sum;
  __syncthreads();
  if (threadIdx.y == 0 && column < columns) {
    T total = 0;
#pragma unroll
    for (int k = 0; k < kRowLanes; ++k) total += lane_sums[k][threadIdx.x];
    out[int64_t(blockIdx.y) * columns + column] = total;
  }
}

template <typename T>
void launch(const T* rows, int64_t row_count, int64_t columns, int64_t chunk_count, T* out, cudaStream_t stream) {
  const int64_t chunk_rows = (row_count + chunk_count - 1) / chunk_count;
  const dim3 grid(unsigned((columns + kColumnsPerBlock - 1) / kColumnsPerBlock), unsigned(chunk_count)),
      block(kColumnsPerBlock, kRowLanes);
  column_sum_kernel<T><<<grid, block, 0, stream>>>(rows, row_count, columns, std::max<int64_t>(1, chunk_rows), out);
  cuda_launch::check_launch("column_sum", "column_sum_kernel");
}

}  // namespace

int64_t chunks(int64_t rows, int64_t columns, int device) {
  const int64_t column_tiles = std::max<int64_t>(1, (columns + kColumnsPerBlock - 1) / kColumnsPerBlock);
  const int64_t wanted =
      std::max<int64_t>(1, cuda_launch::multiprocessors(device, "column_sum") * kBlocksPerSm / column_tiles);
  return std::max<int64_t>(1, std::min({wanted, kMaxChunks, rows / kMinChunkRows}));
}

template <typename T>
void column_sum(const T* rows, int64_t row_count, int64_t columns, T* partials, int64_t chunk_count, T* out,
                cudaStream_t stream) {
  if (columns == 0) return;
  if (chunk_count <= 1) return launch(rows, row_count, columns, 1, out, stream);
  launch(rows, row_count, columns, chunk_count, partials, stream);
  launch(static_cast<const T*>(partials), chunk_count, columns, 1, out, stream);
}

template void column_sum<float>(const float*, int64_t, int64_t, float*, int64_t, float*, cudaStream_t);
template void column_sum<double>(const double*, int64_t, int64_t, double*, int64_t, double*, cudaStream_t);

}  // namespace sfgs::linear::cuda_kernels
