// The shared light of the world normal (model/shading.h): no light at the start, a Lambertian key light with ambient
// share fitted by its nine coefficients to within a few percent, and an avatar's colours are its shading-free
// colours times the light of its posed body-model normals.
#include <cmath>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <gtest/gtest.h>

#include "body/mesh.h"
#include "model/avatar.h"
#include "model/shading.h"
#include "test_avatar_utils.h"

namespace sfgs::testing {
namespace {

using model::Avatar;
using model::AvatarConfig;
using model::AvatarOutput;

at::Tensor random_unit_normals(int64_t count, uint64_t seed) {
  at::Generator generator = at::detail::createCPUGenerator(seed);
  const at::Tensor n = at::empty({count, 3}, at::kDouble).normal_(0.0, 1.0, generator);
  return n / n.norm(2, 1, true);
}

TEST(AvatarShading, StartsAsALightOfOneForEveryNormal) {
  const model::Shading shading;
  const at::Tensor factor = shading->forward(random_unit_normals(500, 1).to(at::kFloat));
  EXPECT_TRUE(factor.equal(at::ones({500, 3})));
}

TEST(AvatarShading, NineCoefficientsFitAKeyLightWithAmbientShareWithinAFewPercent) {
  // The synthetic videos' light (data/mesh_renderer.h): 0.35 ambient + 0.65 x the clamped cosine to a fixed
  // direction. Least squares over the sphere: the quadratic basis cannot bend as sharply as the clamp at the
  // terminator, so the error is largest there, and small everywhere on average.
  const at::Tensor normals = random_unit_normals(20000, 2);
  const at::Tensor light = at::tensor({0.3, 0.5, 0.8}, at::kDouble);
  const at::Tensor lit = 0.35 + 0.65 * normals.matmul(light / light.norm()).clamp_min(0.0);
  const at::Tensor basis = model::ShadingImpl::basis(normals);
  const at::Tensor coefficients = std::get<0>(at::linalg_lstsq(basis, lit.unsqueeze(1)));
  const at::Tensor error = basis.matmul(coefficients).squeeze(1) - lit;
  EXPECT_LT(error.pow(2).mean().sqrt().item<double>(), 0.03);
  EXPECT_LT(error.abs().max().item<double>(), 0.1);
  // Fewer terms (order 1: constant and linear) fit it worse: the quadratic terms carry the light.
  const at::Tensor linear = basis.narrow(1, 0, 4);
  const at::Tensor linear_error =
      linear.matmul(std::get<0>(at::linalg_lstsq(linear, lit.unsqueeze(1)))).squeeze(1) - lit;
  EXPECT_GT(linear_error.pow(2).mean().item<double>(), 2.0 * error.pow(2).mean().item<double>());
}

TEST(AvatarShading, ColoursAreShadingFreeColoursTimesTheLightOfThePosedNormal) {
  Avatar shaded(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*shaded, 0.1, 31);
  AvatarConfig without = small_config();
  without.use_shading = false;
  Avatar unshaded(procedural_avatar_body(), subject_betas(), without);
  copy_parameters(*shaded, *unshaded);
  {
    // A light with a constant share, so no factor is clamped to zero and every point tests the product.
    at::NoGradGuard no_grad;
    for (auto& p : shaded->named_parameters())
      if (p.key() == "shading.coefficients") p.value()[0].fill_(1.0);
  }
  const body::SmplxPose pose = test_pose(7, 0.5, true);
  const AvatarOutput a = shaded->forward(pose, std::nullopt), b = unshaded->forward(pose, std::nullopt);
  ASSERT_TRUE(a.shading.defined());
  EXPECT_FALSE(b.shading.defined());
  EXPECT_GT(a.shading.min().item<double>(), 0.0);
  EXPECT_LT(max_abs_difference(a.colours, b.colours * a.shading), 1e-6);
  // The light is that of the body-model surface's normals at this pose.
  const at::Tensor normals = body::vertex_normals(a.posed_vertices, shaded->faces());
  const at::Tensor coefficients = *shaded->named_parameters().find("shading.coefficients");
  EXPECT_LT(max_abs_difference(a.shading, model::ShadingImpl::basis(normals).matmul(coefficients).clamp_min(0.0)),
            1e-6);
  EXPECT_TRUE(a.means.equal(b.means)) << "the light changes colours only";
  // Turning the body turns its normals: the light changes, the shading-free colours do not (same pose otherwise).
  body::SmplxPose turned = pose;
  turned.global_orient = pose.global_orient + at::tensor({0.0f, 1.2f, 0.0f});
  const AvatarOutput c = shaded->forward(turned, std::nullopt), d = unshaded->forward(turned, std::nullopt);
  EXPECT_GT(max_abs_difference(a.shading, c.shading), 1e-3);
  EXPECT_LT(max_abs_difference(c.colours, d.colours * c.shading), 1e-6);
}

}  // namespace
}  // namespace sfgs::testing
