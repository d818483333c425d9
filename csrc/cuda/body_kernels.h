#pragma once
// CUDA kernels of the body layers, free of torch; the glue (body_cuda.cpp) passes raw pointers.
// kinematic_chain.cu: one thread per batch element walks the joints in order (every parent precedes its children),
// composing each joint's world transform from its parent's, which it reads back from its own output: one launch
// instead of the ~8 small launches per depth level of the LibTorch composition (KinematicTreeImpl::pose_reference).
// rotations.cu: one thread per axis-angle rotation, one launch instead of the ~40 of the composition
// (body::axis_angle_to_matrix_reference).
// vertex_normals.cu: one thread per vertex sums its faces' area-weighted normals in a fixed order and normalises:
// one launch instead of the 18 of the composition (body::vertex_normals_reference), and no atomics.
#include <cuda_runtime_api.h>

#include "body/body_kernel_arrays.h"

namespace sfgs::body::cuda_kernels {

void kinematic_chain_forward(const KinematicChainArrays& arrays, cudaStream_t stream);
void axis_angle_to_matrix_forward(const AxisAngleArrays& arrays, cudaStream_t stream);
void vertex_normals_forward(const VertexNormalArrays& arrays, cudaStream_t stream);

}  // namespace sfgs::body::cuda_kernels
