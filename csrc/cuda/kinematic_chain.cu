// The fused kinematic chain's kernel (body_kernels.h): per joint j with parent p,
//   R_j = R_p L_j,  t_j = t_p + R_p (rest_j - rest_p)   (root: R_0 = L_0, t_0 = rest_0 + translation),
// written as the joint transform [R_j | t_j] and the skinning transform [R_j | t_j - R_j rest_j].
#include <stdexcept>
#include <string>

#include "cuda/body_kernels.h"

namespace sfgs::body::cuda_kernels {
namespace {

constexpr int kThreads = 64;

__global__ void kinematic_chain_kernel(const KinematicChainArrays a) {
  const int64_t b = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (b >= a.batch) return;
  const float* local = a.rotations + b * a.joints * 9;
  const float* rest = a.rest_joints + b * a.joints * 3;
  float* joints_out = a.posed_joints + b * a.joints * 3;
  float* world = a.joint_transforms + b * a.joints * 16;
  float* skinning = a.skinning_transforms + b * a.joints * 16;
  for (int32_t j = 0; j < a.joints; ++j) {
    const int32_t p = a.parents[j];
    float r[9], t[3];
    const float* l = local + j * 9;
    if (p < 0) {
      for (int k = 0; k < 9; ++k) r[k] = l[k];
      for (int k = 0; k < 3; ++k) t[k] = rest[j * 3 + k] + a.translation[b * 3 + k];
    } else {
      const float* w = world + p * 16;  // this thread wrote it at step p < j
      float offset[3];
      for (int k = 0; k < 3; ++k) offset[k] = rest[j * 3 + k] - rest[p * 3 + k];
      for (int row = 0; row < 3; ++row) {
        for (int col = 0; col < 3; ++col)
          r[row * 3 + col] =
              w[row * 4 + 0] * l[0 * 3 + col] + w[row * 4 + 1] * l[1 * 3 + col] + w[row * 4 + 2] * l[2 * 3 + col];
        t[row] = w[row * 4 + 3] + w[row * 4 + 0] * offset[0] + w[row * 4 + 1] * offset[1] + w[row * 4 + 2] * offset[2];
      }
    }
    float* out_world = world + j * 16;
    float* out_skinning = skinning + j * 16;
    for (int row = 0; row < 3; ++row) {
      const float moved =
          r[row * 3 + 0] * rest[j * 3 + 0] + r[row * 3 + 1] * rest[j * 3 + 1] + r[row * 3 + 2] * rest[j * 3 + 2];
      for (int col = 0; col < 3; ++col) out_world[row * 4 + col] = out_skinning[row * 4 + col] = r[row * 3 + col];
      out_world[row * 4 + 3] = t[row];
      out_skinning[row * 4 + 3] = t[row] - moved;
      joints_out[j * 3 + row] = t[row];
    }
    for (int col = 0; col < 4; ++col) out_world[12 + col] = out_skinning[12 + col] = col == 3 ? 1.f : 0.f;
  }
}

}  // namespace

void kinematic_chain_forward(const KinematicChainArrays& a, cudaStream_t stream) {
  if (a.batch == 0 || a.joints == 0) return;
  const unsigned blocks = unsigned((a.batch + kThreads - 1) / kThreads);
  kinematic_chain_kernel<<<blocks, kThreads, 0, stream>>>(a);
  const cudaError_t status = cudaGetLastError();
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs kinematic chain: kernel launch failed: ") + cudaGetErrorString(status));
}

}  // namespace sfgs::body::cuda_kernels
