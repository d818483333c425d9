#pragma once
// The contract between the splatting op (csrc/ops/splat/op.cpp: kernels, autograd) and its two backends (cpu/,
// cuda/). Inputs arrive validated, contiguous, of one floating dtype and on one device. Each backend's forward
// returns the op's outputs and a typed ForwardContext: what its backward needs besides the inputs and outputs.
#include <array>

#include <ATen/core/Tensor.h>

#include "ops/splat/splat.h"
#include "ops/splat/stages.h"
#include "ops/splat/constants.h"

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

// The user's Camera (splat.h, checked by camera_problem) in a backend's compute type.
template <typename T> PinholeCamera<T> to_pinhole(const Camera& c) {
  PinholeCamera<T> cam;
  for (int row = 0; row < 3; ++row) {
    for (int col = 0; col < 3; ++col) cam.rotation[col][row] = T(c.world_to_camera[row * 4 + col]);
    cam.translation[row] = T(c.world_to_camera[row * 4 + 3]);
  }
  cam.fx = T(c.fx);
  cam.fy = T(c.fy);
  cam.cx = T(c.cx);
  cam.cy = T(c.cy);
  cam.width = int(c.width);
  cam.height = int(c.height);
  cam.near_plane = T(c.near_plane);
  cam.far_plane = T(c.far_plane);
  return cam;
}

struct BackendSettings {
  ProjectionSettings projection;
  bool deterministic;  // CUDA: reduce gradients in a fixed order (bit-identical runs); the CPU path always is
};

// The inputs as the raw arrays of stages.h (the tensors must outlive the scene).
template <typename T>
SplatScene<T> make_scene(const SplatInputs& in, const Camera& camera, const BackendSettings& settings) {
  const auto data = [](const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; };
  return SplatScene<T>{to_pinhole<T>(camera), settings.projection,  data(in.means),          data(in.scales),
                       data(in.rotations),    data(in.covariances), data(in.opacities),      data(in.features),
                       data(in.background),   in.means.size(0),     int(in.features.size(1))};
}

// The op's outputs.
struct ForwardOutputs {
  at::Tensor image;  // (H, W, C)
  at::Tensor alpha;  // (H, W)
  at::Tensor depth;  // (H, W): expected depth, expected_depth_of(sum of depth * blend weight, alpha)
  at::Tensor radii;  // (N, 2) int32 half extents in pixels of the alpha >= kMinAlpha ellipse; 0 = culled
};

// Gradients w.r.t. the image, alpha and the weighted depth sum (the op turns the expected-depth gradient into these).
struct OutputGradients {
  at::Tensor image, alpha, depth_sum;  // each may be undefined (no gradient flows into it)
};

struct InputGradients {
  at::Tensor means, scales, rotations, covariances, opacities, features, background;
};

namespace cpu {
// Everything below is indexed as the forward pass left it: intersections in emission order (Gaussian-major, each
// Gaussian's touched tiles row-major), which is also the order of their gradient slots.
struct ForwardContext {
  at::Tensor projected;            // (N, kProjectedWidth) ProjectedField rows; rows of culled Gaussians are zero
  at::Tensor gaussian_offsets;     // (N + 1) int64: Gaussian i owns intersections [offsets[i], offsets[i + 1])
  at::Tensor isect_gaussian;       // (intersections) int64: the Gaussian of each intersection
  at::Tensor tile_offsets;         // (tiles + 1) int64: start of each tile's run in tile_order
  at::Tensor tile_order;           // (intersections) int64: intersections sorted by (tile, depth, Gaussian)
  at::Tensor final_transmittance;  // (H, W)
  at::Tensor contributors;         // (H, W) int32: run position + 1 of the pixel's last blended Gaussian, 0 for none
};
struct Forward {
  ForwardOutputs outputs;
  ForwardContext context;
};
Forward forward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings);
InputGradients backward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                        const ForwardContext& context, const OutputGradients& grads);
}  // namespace cpu

namespace cuda {
// Per-intersection state is in sorted order: each tile's run holds its Gaussians by (depth, index).
struct ForwardContext {
  at::Tensor projected;            // (N, kProjectedWidth) ProjectedField rows; rows of culled Gaussians not written
  at::Tensor tile_rects;           // (N, 4) int16 inclusive tile rectangles (cuda_kernels::TileRect); empty: culled
  at::Tensor isect_gaussian;       // (intersections) int32, tile runs in (depth, index) order
  at::Tensor tile_offsets;         // (tiles + 1) int64: start of each tile's run
  at::Tensor tile_order;           // (tiles) int32: the order in which the blends take the tiles
  at::Tensor final_transmittance;  // (H, W)
  at::Tensor contributors;         // (H, W) int32: run position + 1 of the pixel's last blended Gaussian, 0 for none
  at::Tensor depth_sum;            // (H, W): sum of depth * blend weight
};
struct Forward {
  ForwardOutputs outputs;
  ForwardContext context;
};
// `budget` (may be null): the buffers sized from it, the true counts written to its tensor, no host read (splat.h).
Forward forward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                const BinningBudget* budget);
// image: the forward pass's image output; the backward blend reads what every pixel's composite added up to.
InputGradients backward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                        const at::Tensor& image, const ForwardContext& context, const OutputGradients& grads);
}  // namespace cuda

}  // namespace sfgs::splat
