#pragma once
// Gaussian scenes generated in code, so the demo, tests and benchmarks need no external files.
#include <cstdint>

#include "ops/splat/splat.h"

namespace sfgs::scene {

struct GaussianScene {
  Gaussians gaussians;  // scales + rotations parameterisation, colours as RGB features
  at::Tensor background;
  Camera camera;
};

// A textured torus knot with a checkered floor disc, 3 m in front of a camera at the origin; every call with the
// same arguments gives the same scene.
GaussianScene demo_scene(int64_t count, int64_t width, int64_t height, uint64_t seed, at::ScalarType dtype);

// The avatar-sized workload of the benchmarks: `count` Gaussians uniformly in a 0.5 x 1.8 x 0.3 m box 3 m in front of a
// pinhole camera (fx = fy = 1500, principal point centred), log-uniform scales of 3-15 mm at 167,390 Gaussians
// (times sqrt(167390 / count) otherwise), each axis times a log-uniform 0.8-1.25 factor, random unit quaternions,
// opacities 0.5-1, RGB colours, white background.
GaussianScene avatar_workload(int64_t count, int64_t width, int64_t height, uint64_t seed, at::ScalarType dtype);

}  // namespace sfgs::scene
