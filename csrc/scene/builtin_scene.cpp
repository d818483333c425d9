#include "scene/builtin_scene.h"
#include "common/math_constants.h"
#include "common/constants.h"
#include "ops/splat/constants.h"

#include <cmath>

#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>

namespace sfgs::scene {
namespace {

constexpr int64_t kAvatarReferenceCount = 167390;  // Gaussians of a twice-subdivided SMPL-X mesh

at::Tensor log_uniform(int64_t n, int64_t cols, double lo, double hi, at::Generator& gen) {
  return at::exp(at::empty({n, cols}, at::kDouble).uniform_(std::log(lo), std::log(hi), gen));
}

at::Tensor random_unit_quaternions(int64_t n, at::Generator& gen) {
  const at::Tensor q = at::empty({n, 4}, at::kDouble).normal_(0.0, 1.0, gen);
  return q / q.norm(2, 1, true).clamp_min(kMinQuaternionNorm);
}

GaussianScene finish(at::Tensor means, at::Tensor scales, at::Tensor rotations, at::Tensor opacities,
                     at::Tensor colours, at::Tensor background, Camera camera, at::ScalarType dtype) {
  GaussianScene s;
  s.gaussians.means = means.to(dtype).contiguous();
  s.gaussians.scales = scales.to(dtype).contiguous();
  s.gaussians.rotations = rotations.to(dtype).contiguous();
  s.gaussians.opacities = opacities.to(dtype).contiguous();
  s.gaussians.features = colours.to(dtype).contiguous();
  s.background = background.to(dtype).contiguous();
  s.camera = camera;
  return s;
}

}  // namespace

GaussianScene demo_scene(int64_t count, int64_t width, int64_t height, uint64_t seed, at::ScalarType dtype) {
  TORCH_CHECK(count >= 0, "demo_scene: the Gaussian count must be >= 0, got ", count);
  TORCH_CHECK(width >= 1 && width <= kMaxImageSide && height >= 1 && height <= kMaxImageSide,
              "demo_scene: the image must be 1 to ", kMaxImageSide, " pixels a side, got ", width, " x ", height);
  TORCH_CHECK(dtype == at::kFloat || dtype == at::kDouble, "demo_scene: dtype must be float32 or float64, got ", dtype);
  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  const int64_t floor_count = count / 4;
  const int64_t knot_count = count - floor_count;

  // (3, 2) torus knot: the curve parameter drives position and a rainbow hue.
  const at::Tensor t = at::empty({knot_count}, at::kDouble).uniform_(0.0, 2.0 * kPi, gen);
  const at::Tensor r = 0.35 + 0.15 * at::cos(3.0 * t);
  const at::Tensor tube = at::empty({knot_count, 3}, at::kDouble).normal_(0.0, 0.03, gen);
  const at::Tensor knot =
      at::stack({r * at::cos(2.0 * t), r * at::sin(2.0 * t) - 0.05, 3.0 - 0.15 * at::sin(3.0 * t)}, 1) + tube;
  const at::Tensor knot_colour = at::stack(
      {0.5 + 0.5 * at::cos(t), 0.5 + 0.5 * at::cos(t + 2.0 * kPi / 3.0), 0.5 + 0.5 * at::cos(t + 4.0 * kPi / 3.0)}, 1);

  // Checkered floor disc below the knot.
  const at::Tensor radius = 0.9 * at::sqrt(at::empty({floor_count}, at::kDouble).uniform_(0.0, 1.0, gen));
  const at::Tensor angle = at::empty({floor_count}, at::kDouble).uniform_(0.0, 2.0 * kPi, gen);
  const at::Tensor fx = radius * at::cos(angle), fz = 3.0 + radius * at::sin(angle);
  const at::Tensor floor = at::stack({fx, at::full_like(fx, 0.55), fz}, 1);
  const at::Tensor checker = at::remainder(at::floor(fx * 5.0) + at::floor(fz * 5.0), 2.0).unsqueeze(1);
  const at::Tensor floor_colour = 0.25 + 0.5 * checker.expand({floor_count, 3});

  const at::Tensor means = at::cat({knot, floor});
  const at::Tensor colours = at::cat({knot_colour, floor_colour});
  const at::Tensor scales =
      at::cat({log_uniform(knot_count, 3, 0.006, 0.02, gen),
               log_uniform(floor_count, 3, 0.01, 0.03, gen) * at::tensor({1.0, 0.15, 1.0}, at::kDouble)});
  const at::Tensor opacities = at::empty({count}, at::kDouble).uniform_(0.6, 1.0, gen);
  const double focal = 1.2 * double(std::max(width, height));
  Camera camera = Camera::looking_forward(focal, width, height);
  return finish(means, scales, random_unit_quaternions(count, gen), opacities, colours,
                at::tensor({1.0, 1.0, 1.0}, at::kDouble), camera, dtype);
}

GaussianScene avatar_workload(int64_t count, int64_t width, int64_t height, uint64_t seed, at::ScalarType dtype) {
  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  const at::Tensor unit = at::empty({count, 3}, at::kDouble).uniform_(-0.5, 0.5, gen);
  const at::Tensor means = unit * at::tensor({0.5, 1.8, 0.3}, at::kDouble) + at::tensor({0.0, 0.0, 3.0}, at::kDouble);
  const double density = std::sqrt(double(kAvatarReferenceCount) / double(std::max<int64_t>(count, 1)));
  const at::Tensor base = log_uniform(count, 1, 0.003, 0.015, gen) * density;
  const at::Tensor scales = base * log_uniform(count, 3, 0.8, 1.25, gen);
  const at::Tensor opacities = at::empty({count}, at::kDouble).uniform_(0.5, 1.0, gen);
  const at::Tensor colours = at::empty({count, 3}, at::kDouble).uniform_(0.0, 1.0, gen);
  Camera camera = Camera::looking_forward(1500.0, width, height);
  return finish(means, scales, random_unit_quaternions(count, gen), opacities, colours,
                at::tensor({1.0, 1.0, 1.0}, at::kDouble), camera, dtype);
}

}  // namespace sfgs::scene
