// The mesh propagation's kernels. A replayed frame runs them inside its CUDA graph; a ring holds hundreds to a few
// thousand points and a pass reads each free point's few neighbours, so what costs is the launches (one a ring, one
// a pass) and the memory latency a point waits on (mesh_propagation_math.h reads kRowsAtOnce neighbours at a time).
#include <cstdint>
#include <utility>

#include "cuda/launch_geometry.cuh"
#include "ops/mesh_propagation/mesh_propagation_kernels.h"

namespace sfgs::mesh_propagation::cuda_kernels {
namespace {

constexpr int kThreads = 256;
constexpr int kBlocksPerSm = 8;

void check_launch(const char* kernel) { cuda_launch::check_launch("mesh_propagation", kernel); }

unsigned blocks_for(int64_t work, int device) {
  return unsigned(cuda_launch::grid_stride_blocks(work, kThreads, kBlocksPerSm, device, "mesh_propagation"));
}

template <typename T>
__global__ void __launch_bounds__(kThreads) fill_ring_kernel(const PropagationArrays<T> a, int64_t begin, int64_t end) {
  const int64_t stride = int64_t(gridDim.x) * blockDim.x;
  for (int64_t i = begin + int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < end; i += stride) fill_ring_point(a, i);
}

template <typename T>
__global__ void __launch_bounds__(kThreads) smooth_kernel(const PropagationArrays<T> a, const T* from, T* to) {
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < a.free_count;
       i += int64_t(gridDim.x) * blockDim.x)
    smooth_free_point(a, i, from, to);
}

template <typename T>
__global__ void __launch_bounds__(kThreads) blend_kernel(const PropagationArrays<T> a, const T* propagated) {
  const int64_t count = a.point_count * a.channels;
  for (int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < count; i += int64_t(gridDim.x) * blockDim.x)
    a.out[i] = blend_by_trust(a.trust[i / a.channels], a.values[i], propagated[i]);
}

}  // namespace

template <typename T>
void propagate(const PropagationArrays<T>& a, const std::vector<int64_t>& ring_offsets, int64_t passes, int device,
               cudaStream_t stream) {
  const int64_t values = a.point_count * a.channels;
  for (size_t r = 0; r + 1 < ring_offsets.size(); ++r) {
    fill_ring_kernel<T><<<blocks_for(ring_offsets[r + 1] - ring_offsets[r], device), kThreads, 0, stream>>>(
        a, ring_offsets[r], ring_offsets[r + 1]);
    check_launch("fill_ring_kernel");
  }
  // Both buffers hold the trusted rows: a pass writes the free rows of one from the other.
  cuda_launch::check(cudaMemcpyAsync(a.scratch, a.filled, sizeof(T) * size_t(values), cudaMemcpyDeviceToDevice, stream),
                     "mesh_propagation", "copying the filled values");
  T* from = a.filled;
  T* to = a.scratch;
  for (int64_t pass = 0; pass < passes && a.free_count > 0; ++pass) {
    smooth_kernel<T><<<blocks_for(a.free_count, device), kThreads, 0, stream>>>(a, from, to);
    check_launch("smooth_kernel");
    std::swap(from, to);
  }
  blend_kernel<T><<<blocks_for(values, device), kThreads, 0, stream>>>(a, from);
  check_launch("blend_kernel");
}

template void propagate<float>(const PropagationArrays<float>&, const std::vector<int64_t>&, int64_t, int,
                               cudaStream_t);
template void propagate<double>(const PropagationArrays<double>&, const std::vector<int64_t>&, int64_t, int,
                                cudaStream_t);

}  // namespace sfgs::mesh_propagation::cuda_kernels
