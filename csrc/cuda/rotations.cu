// The fused axis-angle to matrix kernel (body_kernels.h): one thread per rotation evaluates Rodrigues' formula as
// body::axis_angle_to_matrix_reference does, R = I + a K + b K^2 with a = sin(t)/t and b = 0.5 (sin(t/2)/(t/2))^2,
// and their even series in t below series_angle.
#include <stdexcept>
#include <string>

#include "cuda/body_kernels.h"

namespace sfgs::body::cuda_kernels {
namespace {

constexpr int kThreads = 128;

// Horner evaluation of c0 + c1 x + ... + c4 x^4.
__device__ float series(float x, float c0, float c1, float c2, float c3, float c4) {
  return (((c4 * x + c3) * x + c2) * x + c1) * x + c0;
}

__global__ void axis_angle_to_matrix_kernel(const AxisAngleArrays a) {
  const int64_t i = int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
  if (i >= a.count) return;
  const float x = a.axis_angle[i * 3], y = a.axis_angle[i * 3 + 1], z = a.axis_angle[i * 3 + 2];
  const float theta2 = x * x + y * y + z * z;
  float sinc, half;  // a and b of the formula
  if (theta2 < a.series_angle * a.series_angle) {
    sinc = series(theta2, 1.f, -1.f / 6, 1.f / 120, -1.f / 5040, 1.f / 362880);
    half = series(theta2, 0.5f, -1.f / 24, 1.f / 720, -1.f / 40320, 1.f / 3628800);
  } else {
    const float theta = sqrtf(theta2);
    const float half_sinc = sinf(0.5f * theta) / (0.5f * theta);
    sinc = sinf(theta) / theta;
    half = 0.5f * half_sinc * half_sinc;
  }
  // K = [v]_x and K^2 = v v^T - t^2 I.
  const float k[9] = {0.f, -z, y, z, 0.f, -x, -y, x, 0.f};
  const float v[3] = {x, y, z};
  float* r = a.matrices + i * 9;
  for (int row = 0; row < 3; ++row)
    for (int col = 0; col < 3; ++col) {
      const float identity = row == col ? 1.f : 0.f;
      r[row * 3 + col] = identity + sinc * k[row * 3 + col] + half * (v[row] * v[col] - theta2 * identity);
    }
}

}  // namespace

void axis_angle_to_matrix_forward(const AxisAngleArrays& a, cudaStream_t stream) {
  if (a.count == 0) return;
  axis_angle_to_matrix_kernel<<<unsigned((a.count + kThreads - 1) / kThreads), kThreads, 0, stream>>>(a);
  const cudaError_t status = cudaGetLastError();
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs axis-angle rotations: launch failed: ") + cudaGetErrorString(status));
}

}  // namespace sfgs::body::cuda_kernels
