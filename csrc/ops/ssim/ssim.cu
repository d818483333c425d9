// The fused SSIM kernels. A block of 32 x 8 threads takes a tile of 32 columns and tile_rows<T>() rows of one
// channel: it loads the tile and a halo of kWindowRadius pixels on every side into shared memory (zeros outside the
// image: the zero border), filters every halo row horizontally into shared memory, then each thread filters its
// pixels vertically and takes ssim_math.h's per-pixel step. The forward sums the SSIM map of its tile into one
// partial sum (a fixed order: the result does not depend on the scheduling) and writes the three derivative maps;
// the backward filters those maps the same way and combines them into the prediction's gradient.
#include <stdexcept>
#include <string>

#include "ops/ssim/constants.h"
#include "cuda/launch_geometry.cuh"
#include "ops/ssim/ssim_kernels.h"
#include "cuda/warp_utils.cuh"

namespace sfgs::ssim::cuda_kernels {
namespace {

using splat::cuda_kernels::warp_sum;

constexpr int kTileColumns = 32;  // a warp across a tile row: shared-memory rows read without bank conflicts
constexpr int kThreadRows = 8;
constexpr int kThreads = kTileColumns * kThreadRows;
constexpr int kHaloColumns = kTileColumns + 2 * kWindowRadius;
constexpr int kMomentMaps = 5;  // mu_x, mu_y, xx, yy, xy

// A float64 tile has half the rows, so its shared memory stays within the static 48 KiB.
template <typename T> constexpr int tile_rows() { return sizeof(T) > 4 ? kSsimTileRows / 2 : kSsimTileRows; }

template <typename T> constexpr int halo_rows() { return tile_rows<T>() + 2 * kWindowRadius; }

static_assert(kSsimTileRows % (2 * kThreadRows) == 0, "every thread takes whole rows of a tile in both dtypes");

// The tile's first pixel and channel.
struct TileOrigin {
  int row, column, channel;
};

__device__ __forceinline__ TileOrigin tile_origin(int rows) {
  return TileOrigin{int(blockIdx.y) * rows, int(blockIdx.x) * kTileColumns, int(blockIdx.z)};
}

__device__ __forceinline__ bool inside(int row, int column, int height, int width) {
  return row >= 0 && row < height && column >= 0 && column < width;
}

// Every halo row's horizontal window: rows[m][r][j] = sum_k taps[k] halo[m][r][j + k] for each of kMaps maps.
template <typename T, int kMaps>
__device__ __forceinline__ void filter_halo_rows(const T* taps, const T (*halo)[halo_rows<T>()][kHaloColumns],
                                                 T (*rows)[halo_rows<T>()][kTileColumns], int thread) {
  for (int i = thread; i < halo_rows<T>() * kTileColumns; i += kThreads) {
    const int r = i / kTileColumns, j = i % kTileColumns;
#pragma unroll
    for (int m = 0; m < kMaps; ++m) {
      T sum = taps[0] * halo[m][r][j];
#pragma unroll
      for (int k = 1; k < kSsimWindowSize; ++k) sum += taps[k] * halo[m][r][j + k];
      rows[m][r][j] = sum;
    }
  }
}

// The vertical window over one map's filtered rows at tile row r, column j (halo row r is the window's first).
template <typename T>
__device__ __forceinline__ T filter_column(const T* taps, const T (*rows)[kTileColumns], int r, int j) {
  T sum = taps[0] * rows[r][j];
#pragma unroll
  for (int k = 1; k < kSsimWindowSize; ++k) sum += taps[k] * rows[r + k][j];
  return sum;
}

template <typename T> __global__ void __launch_bounds__(kThreads) forward_kernel(const SsimArrays<T> a) {
  constexpr int kRows = tile_rows<T>(), kHaloRows = halo_rows<T>();
  // The products x^2, y^2 and x y are formed from the halo of x and y in the horizontal pass.
  __shared__ T halo[2][kHaloRows][kHaloColumns];
  __shared__ T rows[kMomentMaps][kHaloRows][kTileColumns];
  __shared__ T warp_totals[kThreadRows];
  const TileOrigin tile = tile_origin(kRows);
  const int thread = threadIdx.y * kTileColumns + threadIdx.x;
  for (int i = thread; i < kHaloRows * kHaloColumns; i += kThreads) {
    const int r = i / kHaloColumns, j = i % kHaloColumns;
    const int row = tile.row + r - kWindowRadius, column = tile.column + j - kWindowRadius;
    const bool in_image = inside(row, column, a.height, a.width);
    const int64_t at = (int64_t(row) * a.width + column) * a.channels + tile.channel;
    halo[0][r][j] = in_image ? a.prediction[at] : T(0);
    halo[1][r][j] = in_image ? a.target[at] : T(0);
  }
  __syncthreads();
  for (int i = thread; i < kHaloRows * kTileColumns; i += kThreads) {
    const int r = i / kTileColumns, j = i % kTileColumns;
    T sums[kMomentMaps] = {};
#pragma unroll
    for (int k = 0; k < kSsimWindowSize; ++k) {
      const T x = halo[0][r][j + k], y = halo[1][r][j + k];
      const T products[kMomentMaps] = {x, y, x * x, y * y, x * y};
#pragma unroll
      for (int m = 0; m < kMomentMaps; ++m) sums[m] += a.taps[k] * products[m];
    }
#pragma unroll
    for (int m = 0; m < kMomentMaps; ++m) rows[m][r][j] = sums[m];
  }
  __syncthreads();
  const int64_t plane = int64_t(a.height) * a.width;
  T total = 0;
#pragma unroll
  for (int q = 0; q < kRows / kThreadRows; ++q) {
    const int r = threadIdx.y + q * kThreadRows, j = threadIdx.x;
    const int row = tile.row + r, column = tile.column + j;
    if (!inside(row, column, a.height, a.width)) continue;
    const Moments<T> m{filter_column(a.taps, rows[0], r, j), filter_column(a.taps, rows[1], r, j),
                       filter_column(a.taps, rows[2], r, j), filter_column(a.taps, rows[3], r, j),
                       filter_column(a.taps, rows[4], r, j)};
    if (!a.derivative_maps) {
      total += ssim_value(m, a.c1, a.c2);
      continue;
    }
    const PixelSsim<T> p = ssim_with_derivatives(m, a.c1, a.c2);
    total += p.value;
    const int64_t at_pixel = tile.channel * plane + int64_t(row) * a.width + column;
    const int64_t map_stride = int64_t(a.channels) * plane;
    a.derivative_maps[at_pixel] = p.d_mu_x;
    a.derivative_maps[map_stride + at_pixel] = p.d_xx;
    a.derivative_maps[2 * map_stride + at_pixel] = p.d_xy;
  }
  total = warp_sum(total);
  if (threadIdx.x == 0) warp_totals[threadIdx.y] = total;
  __syncthreads();
  if (thread == 0) {
    T block_total = warp_totals[0];
#pragma unroll
    for (int w = 1; w < kThreadRows; ++w) block_total += warp_totals[w];
    a.partial_sums[(int64_t(blockIdx.z) * gridDim.y + blockIdx.y) * gridDim.x + blockIdx.x] = block_total;
  }
}

template <typename T> __global__ void __launch_bounds__(kThreads) backward_kernel(const SsimGradientArrays<T> a) {
  constexpr int kRows = tile_rows<T>(), kHaloRows = halo_rows<T>();
  __shared__ T halo[kDerivativeMaps][kHaloRows][kHaloColumns];
  __shared__ T rows[kDerivativeMaps][kHaloRows][kTileColumns];
  const TileOrigin tile = tile_origin(kRows);
  const int thread = threadIdx.y * kTileColumns + threadIdx.x;
  const int64_t plane = int64_t(a.height) * a.width, map_stride = int64_t(a.channels) * plane;
  for (int i = thread; i < kHaloRows * kHaloColumns; i += kThreads) {
    const int r = i / kHaloColumns, j = i % kHaloColumns;
    const int row = tile.row + r - kWindowRadius, column = tile.column + j - kWindowRadius;
    const bool in_image = inside(row, column, a.height, a.width);
    const int64_t at = tile.channel * plane + int64_t(row) * a.width + column;
#pragma unroll
    for (int m = 0; m < kDerivativeMaps; ++m) halo[m][r][j] = in_image ? a.derivative_maps[m * map_stride + at] : T(0);
  }
  __syncthreads();
  filter_halo_rows<T, kDerivativeMaps>(a.taps, halo, rows, thread);
  __syncthreads();
  const T scale = *a.grad_mean * a.inverse_count;
#pragma unroll
  for (int q = 0; q < kRows / kThreadRows; ++q) {
    const int r = threadIdx.y + q * kThreadRows, j = threadIdx.x;
    const int row = tile.row + r, column = tile.column + j;
    if (!inside(row, column, a.height, a.width)) continue;
    const int64_t at_pixel = (int64_t(row) * a.width + column) * a.channels + tile.channel;
    a.grad_prediction[at_pixel] =
        prediction_gradient(scale, filter_column(a.taps, rows[0], r, j), filter_column(a.taps, rows[1], r, j),
                            filter_column(a.taps, rows[2], r, j), a.prediction[at_pixel], a.target[at_pixel]);
  }
}

// The grid of tiles over an image; CUDA bounds its y and z extents at 65535.
template <typename T> dim3 tile_grid(int64_t height, int64_t width, int64_t channels) {
  const int64_t columns = (width + kTileColumns - 1) / kTileColumns,
                rows = (height + tile_rows<T>() - 1) / tile_rows<T>();
  constexpr int64_t kMaxExtent = 65535;
  if (rows > kMaxExtent || channels > kMaxExtent)
    throw std::runtime_error("sfgs fused_ssim: an image of " + std::to_string(height) + " rows and " +
                             std::to_string(channels) + " channels exceeds the kernels' grid (at most " +
                             std::to_string(kMaxExtent) + " tiles of " + std::to_string(tile_rows<T>()) + " rows and " +
                             std::to_string(kMaxExtent) + " channels)");
  return dim3(unsigned(columns), unsigned(rows), unsigned(channels));
}

}  // namespace

template <typename T> int64_t tile_count(int64_t height, int64_t width, int64_t channels) {
  const dim3 grid = tile_grid<T>(height, width, channels);
  return int64_t(grid.x) * grid.y * grid.z;
}

template <typename T> void forward(const SsimArrays<T>& a, cudaStream_t stream) {
  forward_kernel<T><<<tile_grid<T>(a.height, a.width, a.channels), dim3(kTileColumns, kThreadRows), 0, stream>>>(a);
  cuda_launch::check_launch("fused_ssim", "forward_kernel");
}

template <typename T> void backward(const SsimGradientArrays<T>& a, cudaStream_t stream) {
  backward_kernel<T><<<tile_grid<T>(a.height, a.width, a.channels), dim3(kTileColumns, kThreadRows), 0, stream>>>(a);
  cuda_launch::check_launch("fused_ssim", "backward_kernel");
}

template int64_t tile_count<float>(int64_t, int64_t, int64_t);
template int64_t tile_count<double>(int64_t, int64_t, int64_t);
template void forward<float>(const SsimArrays<float>&, cudaStream_t);
template void forward<double>(const SsimArrays<double>&, cudaStream_t);
template void backward<float>(const SsimGradientArrays<float>&, cudaStream_t);
template void backward<double>(const SsimGradientArrays<double>&, cudaStream_t);

}  // namespace sfgs::ssim::cuda_kernels
