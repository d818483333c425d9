// Stands in for the CUDA backends that are not dispatcher kernels (the body's kernels, and the inference networks,
// mesh propagation and plane sampling, not yet registered: ops/registration.h) in builds without a CUDA LibTorch: their
// callers check available() first and report a clear error, so these entry points are only reached by a caller that
// bypasses it. The registered ops need none: a build without CUDA registers no CUDA kernel.
#include <c10/util/Exception.h>

#include "body/body_backend.h"
#include "ops/gathered_mlp/backend.h"
#include "ops/mesh_propagation/backend.h"
#include "ops/mlp_inference/backend.h"
#include "ops/plane_sampling/backend.h"

namespace sfgs::gathered_mlp::cuda {

bool available() { return false; }
void forward(const GatheredMlpArrays&, at::Device) { TORCH_CHECK(false, "sfgs: this build has no CUDA backend"); }

}  // namespace sfgs::gathered_mlp::cuda

namespace sfgs::mlp_inference::cuda {

bool available() { return false; }
bool fits(int, int, at::Device) { return false; }
void forward(const MlpInferenceArrays&, at::Device) { TORCH_CHECK(false, "sfgs: this build has no CUDA backend"); }

}  // namespace sfgs::mlp_inference::cuda

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

namespace sfgs::plane_sampling::cuda {

void gradient(const PlaneGradientArrays<float>&, at::Device) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend");
}
void gradient(const PlaneGradientArrays<double>&, at::Device) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend");
}

}  // namespace sfgs::plane_sampling::cuda

namespace sfgs::mesh_propagation::cuda {

bool available() { return false; }
void propagate(const PropagationArrays<float>&, const std::vector<int64_t>&, int64_t, at::Device) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend");
}
void propagate(const PropagationArrays<double>&, const std::vector<int64_t>&, int64_t, at::Device) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend");
}

}  // namespace sfgs::mesh_propagation::cuda
