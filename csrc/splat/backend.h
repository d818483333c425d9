#pragma once
// The contract between the splatting op (splat.cpp: validation, autograd) and its two backends (csrc/cpu,
// csrc/cuda). Inputs arrive validated, contiguous, of one floating dtype and on one device.
#include <array>
#include <vector>

#include <ATen/core/Tensor.h>

#include "splat/pair_math.h"

namespace sfgs::splat {

// Differentiable inputs. Exactly one parameterisation is defined: scales + rotations, or covariances.
struct SplatInputs {
  at::Tensor means;        // (N, 3)
  at::Tensor scales;       // (N, 3) or undefined
  at::Tensor rotations;    // (N, 4) quaternions (w, x, y, z), any norm; or undefined
  at::Tensor covariances;  // (N, 6) packed (xx, xy, xz, yy, yz, zz); or undefined
  at::Tensor opacities;    // (N)
  at::Tensor features;     // (N, C)
  at::Tensor background;   // (C)
  bool uses_covariances() const { return covariances.defined(); }
};

// Camera in double precision; backends convert to their compute type.
struct CameraSpec {
  std::array<double, 16> world_to_camera;  // row-major 4x4
  double fx, fy, cx, cy;
  int width, height;
  double near_plane, far_plane;
};

template <typename T> PinholeCamera<T> to_pinhole(const CameraSpec& c) {
  PinholeCamera<T> cam;
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 3; ++col) cam.rotation[col][row] = T(c.world_to_camera[row * 4 + col]);
    cam.translation[row] = T(c.world_to_camera[row * 4 + 3]);
  }
  cam.fx = T(c.fx); cam.fy = T(c.fy); cam.cx = T(c.cx); cam.cy = T(c.cy);
  cam.width = c.width; cam.height = c.height;
  cam.near_plane = T(c.near_plane); cam.far_plane = T(c.far_plane);
  return cam;
}

struct BackendSettings {
  ProjectionSettings projection;
  bool deterministic;  // CUDA: reduce gradients in a fixed order (bit-identical runs); the CPU path always is
};

// Forward results plus whatever the backend needs to replay the blend backwards.
struct ForwardOutputs {
  at::Tensor image;      // (H, W, C)
  at::Tensor alpha;      // (H, W)
  at::Tensor depth;      // (H, W): expected depth, expected_depth_of(sum of depth * blend weight, alpha)
  at::Tensor radii;      // (N, 2) int32 half extents in pixels of the alpha >= kMinAlpha ellipse; 0 = culled
  std::vector<at::Tensor> saved;  // backend-private state for backward
};

// Gradients w.r.t. the image, alpha and the weighted depth sum (the op turns the expected-depth gradient into these).
struct OutputGradients {
  at::Tensor image, alpha, depth_sum;  // each may be undefined (no gradient flows into it)
};

struct InputGradients {
  at::Tensor means, scales, rotations, covariances, opacities, features, background;
};

namespace cpu {
ForwardOutputs forward(const SplatInputs& in, const CameraSpec& camera, const BackendSettings& settings);
InputGradients backward(const SplatInputs& in, const CameraSpec& camera, const BackendSettings& settings,
                        const ForwardOutputs& forward, const OutputGradients& grads);
}  // namespace cpu

namespace cuda {
bool available();  // compiled with CUDA support
ForwardOutputs forward(const SplatInputs& in, const CameraSpec& camera, const BackendSettings& settings);
InputGradients backward(const SplatInputs& in, const CameraSpec& camera, const BackendSettings& settings,
                        const ForwardOutputs& forward, const OutputGradients& grads);
}  // namespace cuda

}  // namespace sfgs::splat
