#pragma once
// The contract between the body layers (kinematics.cpp, mesh.cpp: when to fuse, validation, outputs) and their
// fused kernels' CUDA glue (csrc/cuda/body_cuda.cpp; csrc/cuda/cuda_unavailable.cpp in builds without CUDA).
#include <c10/core/Device.h>

#include "body/body_kernel_arrays.h"

namespace sfgs::body::cuda {

bool available();
// Each queues its kernel on the device's current stream; the arrays are validated and contiguous.
void kinematic_chain(const KinematicChainArrays& arrays, at::Device device);
void axis_angle_to_matrix(const AxisAngleArrays& arrays, at::Device device);
void vertex_normals(const VertexNormalArrays& arrays, at::Device device);

}  // namespace sfgs::body::cuda
