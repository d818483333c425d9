#pragma once
// CUDA kernels of the mesh propagation (csrc/ops/mesh_propagation/mesh_propagation.h), free of torch so that nvcc
// compiles them without a CUDA LibTorch: a launch a ring (its points, a thread each), a copy, a launch a smoothing
// pass over the free points and one for the blend, all on `stream` with no host synchronisation. The glue
// (mesh_propagation_cuda.cpp) passes raw pointers.
#include <cstdint>
#include <vector>

#include <cuda_runtime_api.h>

#include "ops/mesh_propagation/mesh_propagation_math.h"

namespace sfgs::mesh_propagation::cuda_kernels {

template <typename T>
void propagate(const PropagationArrays<T>& arrays, const std::vector<int64_t>& ring_offsets, int64_t passes, int device,
               cudaStream_t stream);

}  // namespace sfgs::mesh_propagation::cuda_kernels
