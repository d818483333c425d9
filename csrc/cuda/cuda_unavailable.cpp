// Stands in for the body's CUDA kernels (layers of the body model, not dispatcher ops) in builds without a CUDA
// LibTorch: their callers check available() first and report a clear error, so these entry points are only reached
// by a caller that bypasses it. The ops need none: a build without CUDA registers no CUDA kernel (ops/registration.h).
#include <c10/util/Exception.h>

#include "body/body_backend.h"

namespace sfgs::body::cuda {

bool available() { return false; }
void kinematic_chain(const KinematicChainArrays&, at::Device) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend");
}
void axis_angle_to_matrix(const AxisAngleArrays&, at::Device) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend");
}
void vertex_normals(const VertexNormalArrays&, at::Device) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend");
}

}  // namespace sfgs::body::cuda
