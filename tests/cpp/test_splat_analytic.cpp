// Cases with closed-form answers: one Gaussian's peak and footprint, ordering and occlusion of two, early
// termination, background showing through, principal-point shifts, the empty scene.
#include <cmath>

#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "splat_test_utils.h"
#include "ops/splat/constants.h"

namespace sfgs::testing {
namespace {

constexpr double kExact = 1e-12;

// Isotropic Gaussians centred on the optical axis of a 33 x 33 camera (focal 100): pixel (16, 16)'s centre is
// exactly on the axis, so each Gaussian's projected mean is that pixel centre.
struct AxisScene {
  Gaussians g;
  at::Tensor background;
  Camera camera = Camera::looking_forward(100.0, 33, 33);

  void add(double depth, double scale, double opacity, std::vector<double> colour) {
    const auto row = [](std::vector<double> v) { return at::tensor(v, at::kDouble).unsqueeze(0); };
    const auto append = [](at::Tensor& t, const at::Tensor& r) { t = t.defined() ? at::cat({t, r}) : r; };
    append(g.means, row({0.0, 0.0, depth}));
    append(g.scales, row({scale, scale, scale}));
    append(g.rotations, row({1.0, 0.0, 0.0, 0.0}));
    append(g.opacities, at::tensor({opacity}, at::kDouble));
    append(g.features, row(colour));
  }
};

TEST(SplatAnalytic, SingleGaussianPeakAndFootprint) {
  AxisScene s;
  s.add(2.0, 0.04, 0.8, {1.0, 0.5, 0.25});  // projected standard deviation 100 * 0.04 / 2 = 2 px
  s.background = at::zeros({3}, at::kDouble);
  const RenderResult r = render(s.g, s.background, s.camera);
  const double variance = 4.0 + kLowPassVariancePx2;
  EXPECT_NEAR(r.alpha[16][16].item<double>(), 0.8, kExact);
  EXPECT_NEAR(r.image[16][16][1].item<double>(), 0.8 * 0.5, kExact);
  EXPECT_NEAR(r.depth[16][16].item<double>(), 2.0, kExact);
  const auto visible_alpha = [](double a) { return a >= kMinAlpha ? a : 0.0; };
  for (int k = 1; k <= 6; ++k) {
    const double expected = 0.8 * std::exp(-0.5 * k * k / variance);
    EXPECT_NEAR(r.alpha[16][16 + k].item<double>(), expected, kExact) << "offset " << k;
    EXPECT_NEAR(r.alpha[16 - k][16].item<double>(), expected, kExact) << "offset " << k;
    EXPECT_NEAR(r.alpha[16 + k][16 + k].item<double>(), visible_alpha(0.8 * std::exp(-k * k / variance)), kExact) << k;
  }
  EXPECT_EQ(r.alpha[16 + 5][16 + 5].item<double>(), 0.0) << "0.8 exp(-25 / 4.3) < 1/255 is skipped";
  // alpha < 1/255 from 7 px on: the footprint ends there.
  EXPECT_EQ(r.alpha[16][16 + 7].item<double>(), 0.0);
  EXPECT_EQ(r.alpha[16][16 - 7].item<double>(), 0.0);
  const int expected_radius = int(std::ceil(std::sqrt(2.0 * std::log(0.8 / kMinAlpha) * variance)));
  EXPECT_EQ(r.radii[0][0].item<int>(), expected_radius);
  EXPECT_EQ(r.radii[0][1].item<int>(), expected_radius);
  EXPECT_TRUE(r.visible[0].item<bool>());

  RenderOptions aa;
  aa.antialiased = true;
  const RenderResult a = render(s.g, s.background, s.camera, aa);
  EXPECT_NEAR(a.alpha[16][16].item<double>(), 0.8 * 4.0 / variance, kExact);  // sqrt(det 4^2 / det 4.3^2)

  RenderOptions sharp;
  sharp.low_pass = false;
  const RenderResult n = render(s.g, s.background, s.camera, sharp);
  EXPECT_NEAR(n.alpha[16][16 + 3].item<double>(), 0.8 * std::exp(-0.5 * 9.0 / 4.0), kExact);
}

TEST(SplatAnalytic, TwoGaussiansBlendInDepthOrderWhateverTheirIndex) {
  const std::vector<double> red{1, 0, 0}, blue{0, 0, 1};
  const at::Tensor background = at::tensor({0.0, 1.0, 0.0}, at::kDouble);
  AxisScene front_first, back_first;
  front_first.add(2.0, 0.2, 0.5, red);
  front_first.add(4.0, 0.4, 0.6, blue);
  back_first.add(4.0, 0.4, 0.6, blue);
  back_first.add(2.0, 0.2, 0.5, red);
  const RenderResult a = render(front_first.g, background, front_first.camera);
  const RenderResult b = render(back_first.g, background, back_first.camera);
  // Both are 10 px wide; at the shared centre alpha equals opacity.
  const at::Tensor expected = at::tensor({0.5, 0.5 * 0.4, 0.5 * 0.6}, at::kDouble);
  EXPECT_LE((a.image[16][16] - expected).abs().max().item<double>(), kExact);
  EXPECT_TRUE(at::equal(a.image, b.image));
  EXPECT_NEAR(a.depth[16][16].item<double>(), (0.5 * 2.0 + 0.5 * 0.6 * 4.0) / 0.8, kExact);
}

TEST(SplatAnalytic, OpaqueFrontGaussianOccludesAndBlendingTerminates) {
  const at::Tensor background = at::tensor({0.0, 0.0, 0.0}, at::kDouble);
  AxisScene s;
  for (int i = 0; i < 5; ++i) s.add(2.0 + i, 0.3 * (1 + i), 1.0, {double(i == 0), double(i == 1), double(i >= 2)});
  const RenderResult r = render(s.g, background, s.camera);
  // alpha caps at 0.99: T goes 1 -> 0.01 -> 1e-4(1 + rounding); the third would take it below 1e-4 and stops it.
  const double t1 = 1.0 - kMaxAlpha;
  EXPECT_NEAR(r.image[16][16][0].item<double>(), kMaxAlpha, kExact);
  EXPECT_NEAR(r.image[16][16][1].item<double>(), kMaxAlpha * t1, kExact);
  EXPECT_EQ(r.image[16][16][2].item<double>(), 0.0);
  EXPECT_GE(1.0 - r.alpha.max().item<double>(), kMinTransmittance * (1 - 1e-9));
}

TEST(SplatAnalytic, BackgroundShowsThroughWhereNothingIsInFront) {
  AxisScene s;
  s.add(-2.0, 0.1, 0.9, {1, 1, 1});   // behind the camera
  s.add(0.001, 0.1, 0.9, {1, 1, 1});  // in front of the near plane
  const at::Tensor background = at::tensor({0.2, 0.4, 0.6}, at::kDouble);
  const RenderResult r = render(s.g, background, s.camera);
  EXPECT_TRUE(at::equal(r.image, background.expand({33, 33, 3})));
  EXPECT_EQ(r.alpha.abs().max().item<double>(), 0.0);
  EXPECT_EQ(r.depth.abs().max().item<double>(), 0.0);
  EXPECT_FALSE(r.visible.any().item<bool>());
  EXPECT_EQ(r.radii.abs().max().item<int>(), 0);
}

TEST(SplatAnalytic, PrincipalPointShiftMovesTheImage) {
  SceneSpec spec;
  spec.count = 40;
  spec.width = 45;
  spec.height = 38;
  TestScene s = random_scene(spec, 3);
  const RenderResult base = render(s.gaussians, s.background, s.camera);
  Camera shifted = s.camera;
  shifted.cx += 5;
  shifted.cy -= 3;
  const RenderResult moved = render(s.gaussians, s.background, shifted);
  const at::Tensor expected = base.image.slice(1, 0, spec.width - 5).slice(0, 3, spec.height);
  const at::Tensor got = moved.image.slice(1, 5, spec.width).slice(0, 0, spec.height - 3);
  EXPECT_LE((got - expected).abs().max().item<double>(), 1e-12);
  EXPECT_GT((moved.image - base.image).abs().max().item<double>(), 0.1) << "the shift must change the image";
}

TEST(SplatAnalytic, EmptySceneRendersBackgroundAndGivesItAllTheGradient) {
  Gaussians g;
  g.means = at::zeros({0, 3}, at::kDouble).set_requires_grad(true);
  g.scales = at::zeros({0, 3}, at::kDouble).set_requires_grad(true);
  g.rotations = at::zeros({0, 4}, at::kDouble).set_requires_grad(true);
  g.opacities = at::zeros({0}, at::kDouble).set_requires_grad(true);
  g.features = at::zeros({0, 2}, at::kDouble).set_requires_grad(true);
  const at::Tensor background = at::tensor({0.3, 0.7}, at::kDouble).set_requires_grad(true);
  const Camera camera = Camera::looking_forward(50.0, 20, 13);
  const RenderResult r = render(g, background, camera);
  EXPECT_TRUE(at::equal(r.image, background.detach().expand({13, 20, 2})));
  EXPECT_EQ(r.radii.sizes(), at::IntArrayRef({0, 2}));
  const at::Tensor weights = at::rand({13, 20, 2}, at::kDouble);
  const auto grads = torch::autograd::grad({(r.image * weights).sum()}, {g.means, g.features, background});
  EXPECT_EQ(grads[0].sizes(), at::IntArrayRef({0, 3}));
  EXPECT_EQ(grads[1].sizes(), at::IntArrayRef({0, 2}));
  EXPECT_LE((grads[2] - weights.sum(at::IntArrayRef{0, 1})).abs().max().item<double>(), 1e-12);
}

}  // namespace
}  // namespace sfgs::testing
