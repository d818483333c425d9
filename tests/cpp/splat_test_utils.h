#pragma once
// Shared fixtures of the splatting tests: random scenes kept away from the op's thresholds, an independent
// brute-force reference renderer written with torch operations, and finite differences.
#include <functional>
#include <vector>

#include <ATen/ATen.h>

#include "ops/splat/splat.h"
#include "ops/splat/constants.h"

namespace sfgs::testing {

struct TestScene {
  Gaussians gaussians;
  at::Tensor background;
  Camera camera;
};

struct SceneSpec {
  int64_t count = 10;
  int64_t width = 37;
  int64_t height = 29;
  int64_t channels = 3;
  bool covariances = false;  // covariances (N,6) instead of scales + rotations
  double min_opacity = 0.15;
  double max_opacity = 0.7;
  double min_footprint_px = 1.5;  // projected standard deviation range
  double max_footprint_px = 5.0;
};

// A random scene inside a rotated, translated camera's view with an off-centre principal point.
TestScene random_scene(const SceneSpec& spec, uint64_t seed, at::ScalarType dtype = at::kDouble);

struct ReferenceImage {
  at::Tensor image, alpha, depth;
  // Smallest relative distance of any pair's alpha to kMinAlpha / kMaxAlpha and of any pixel's transmittance to
  // kMinTransmittance: finite differences are only meaningful when this is not tiny.
  double threshold_margin;
};

// Every pixel against every Gaussian in global depth order, no tiles, no culling shortcuts: an independent
// implementation of the op's definition (docs/splatting.md). Differentiable through torch autograd.
ReferenceImage reference_render(const Gaussians& g, const at::Tensor& background, const Camera& camera,
                                const RenderOptions& options = {});

// A random scene whose threshold margin is at least `margin` (tries successive seeds from `seed`).
TestScene smooth_random_scene(const SceneSpec& spec, uint64_t seed, const RenderOptions& options = {},
                              double margin = 1e-3);

// Fixed random weights for a scalar loss over image, alpha and depth.
struct LossWeights {
  at::Tensor image, alpha, depth;
};
LossWeights random_weights(int64_t height, int64_t width, int64_t channels, uint64_t seed, at::ScalarType dtype);
at::Tensor weighted_loss(const at::Tensor& image, const at::Tensor& alpha, const at::Tensor& depth,
                         const LossWeights& w);

// Central finite differences of f w.r.t. every element of `param` (modified in place and restored).
at::Tensor finite_difference(const std::function<double()>& f, at::Tensor param, double step);

// ||a - b|| / ||b|| (0 when both vanish).
double relative_error(const at::Tensor& a, const at::Tensor& b);

// Pointers to the differentiable inputs that are defined, with their names.
std::vector<std::pair<std::string, at::Tensor*>> differentiable_inputs(TestScene& s);

}  // namespace sfgs::testing
