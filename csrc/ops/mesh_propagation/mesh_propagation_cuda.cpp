// CUDA backend of the mesh propagation: the torch side of mesh_propagation_kernels.h, queued on the device's current
// stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/mesh_propagation/mesh_propagation_kernels.h"
#include "ops/mesh_propagation/backend.h"

namespace sfgs::mesh_propagation::cuda {

void propagate(const PropagationArrays<float>& a, const std::vector<int64_t>& offsets, int64_t passes,
               at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::propagate(a, offsets, passes, device.index(), at::cuda::getCurrentCUDAStream());
}

void propagate(const PropagationArrays<double>& a, const std::vector<int64_t>& offsets, int64_t passes,
               at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::propagate(a, offsets, passes, device.index(), at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::mesh_propagation::cuda
