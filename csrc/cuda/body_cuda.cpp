// CUDA backend of the body layers' fused kernels: the torch side of body_kernels.h, on the current stream.
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "body/body_backend.h"
#include "cuda/body_kernels.h"

namespace sfgs::body::cuda {

bool available() { return true; }

void kinematic_chain(const KinematicChainArrays& arrays, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::kinematic_chain_forward(arrays, at::cuda::getCurrentCUDAStream());
}

void axis_angle_to_matrix(const AxisAngleArrays& arrays, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::axis_angle_to_matrix_forward(arrays, at::cuda::getCurrentCUDAStream());
}

void vertex_normals(const VertexNormalArrays& arrays, at::Device device) {
  const c10::cuda::CUDAGuard guard(device);
  cuda_kernels::vertex_normals_forward(arrays, at::cuda::getCurrentCUDAStream());
}

}  // namespace sfgs::body::cuda
