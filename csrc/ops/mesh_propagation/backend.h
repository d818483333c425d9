#pragma once
// The contract between the mesh propagation (csrc/ops/mesh_propagation/mesh_propagation.cpp: the plan, validation) and
// its two backends (csrc/ops/mesh_propagation/mesh_propagation_cpu.cpp,
// csrc/ops/mesh_propagation/mesh_propagation_cuda.cpp): arrays of validated, contiguous tensors of one dtype on one
// device, the rings' bounds on the host (ring r fills ring_points[ring_offsets[r] .. ring_offsets[r + 1])), and the
// number of smoothing passes.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

#include "ops/mesh_propagation/mesh_propagation_math.h"

namespace sfgs::mesh_propagation {

namespace cpu {
void propagate(const PropagationArrays<float>& arrays, const std::vector<int64_t>& ring_offsets, int64_t passes);
void propagate(const PropagationArrays<double>& arrays, const std::vector<int64_t>& ring_offsets, int64_t passes);
}  // namespace cpu

// On `device`'s current stream, without a host synchronisation (a CUDA graph records it).
namespace cuda {
void propagate(const PropagationArrays<float>& arrays, const std::vector<int64_t>& ring_offsets, int64_t passes,
               at::Device device);
void propagate(const PropagationArrays<double>& arrays, const std::vector<int64_t>& ring_offsets, int64_t passes,
               at::Device device);
}  // namespace cuda

}  // namespace sfgs::mesh_propagation
