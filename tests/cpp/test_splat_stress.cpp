// Numerical stress: degenerate, extreme and non-finite inputs. Valid inputs never give NaN or Inf in outputs or
// gradients; Gaussians that cannot be rendered are culled (visible = false, zero gradient). docs/splatting.md lists
// which inputs are culled and which are errors (test_splat_validation.cpp).
#include <cmath>
#include <limits>
#include <string>

#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "splat_test_utils.h"
#include "ops/splat/constants.h"

namespace sfgs::testing {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

struct StressResult {
  RenderResult render;
  std::vector<at::Tensor> grads;  // w.r.t. differentiable_inputs order
};

// Renders, backpropagates a random-weight loss and checks every output and gradient is finite.
StressResult render_and_check(TestScene& s, const RenderOptions& options = {}) {
  auto inputs = differentiable_inputs(s);
  std::vector<at::Tensor> leaves;
  for (auto& [name, t] : inputs) leaves.push_back(t->detach().set_requires_grad(true)), *t = leaves.back();
  StressResult out;
  out.render = render(s.gaussians, s.background, s.camera, options);
  const RenderResult& r = out.render;
  EXPECT_TRUE(r.image.isfinite().all().item<bool>());
  EXPECT_TRUE(r.alpha.isfinite().all().item<bool>());
  EXPECT_TRUE(r.depth.isfinite().all().item<bool>());
  EXPECT_GE(r.alpha.min().item<double>(), 0.0);
  EXPECT_LE(r.alpha.max().item<double>(), 1.0 - kMinTransmittance + 1e-6);
  const LossWeights w = random_weights(s.camera.height, s.camera.width, r.image.size(2), 1, r.image.scalar_type());
  out.grads = torch::autograd::grad({weighted_loss(r.image, r.alpha, r.depth, w)}, leaves, {}, false, false, true);
  for (size_t i = 0; i < leaves.size(); ++i) {
    EXPECT_TRUE(out.grads[i].defined()) << inputs[i].first;
    if (out.grads[i].defined()) EXPECT_TRUE(out.grads[i].isfinite().all().item<bool>()) << inputs[i].first;
  }
  return out;
}

TestScene base_scene(int64_t count = 8) {
  SceneSpec spec;
  spec.count = count;
  return random_scene(spec, 17);
}

void set_row(at::Tensor& t, int64_t row, std::vector<double> values) {
  t.select(0, row).copy_(at::tensor(values, t.options()));
}

TEST(SplatStress, ZeroTinyAndHugeScales) {
  for (double scale : {0.0, 1e-9, 1e6}) {
    TestScene s = base_scene();
    set_row(s.gaussians.scales, 0, {scale, scale, scale});
    set_row(s.gaussians.scales, 1, {scale, 0.01, 0.01});
    const StressResult r = render_and_check(s);
    EXPECT_TRUE(r.render.visible[0].item<bool>()) << "scale " << scale << ": the low-pass keeps it renderable";
  }
  TestScene s = base_scene();
  set_row(s.gaussians.scales, 0, {0.0, 0.0, 0.0});
  RenderOptions sharp;
  sharp.low_pass = false;
  const StressResult r = render_and_check(s, sharp);
  EXPECT_FALSE(r.render.visible[0].item<bool>()) << "a point without the low-pass has no footprint";
  EXPECT_EQ(r.grads[0][0].abs().sum().item<double>(), 0.0);
}

TEST(SplatStress, SingularAndIndefiniteCovariances) {
  SceneSpec spec;
  spec.covariances = true;
  TestScene s = random_scene(spec, 5);
  set_row(s.gaussians.covariances, 0, {1e-4, 0, 0, 0, 0, 0});           // rank 1: a needle
  set_row(s.gaussians.covariances, 1, {1e-4, 0, 0, 1e-4, 0, 0});        // rank 2: a disc seen face-on
  set_row(s.gaussians.covariances, 2, {1e-4, 2e-4, 0, 1e-4, 0, 1e-4});  // indefinite (eigenvalue -1e-4)
  set_row(s.gaussians.covariances, 3, {-1e-4, 0, 0, 1e-4, 0, 1e-4});    // negative variance
  set_row(s.gaussians.covariances, 4, {0, 0, 0, 0, 0, 0});              // a point
  const StressResult r = render_and_check(s);
  EXPECT_TRUE(r.render.visible[0].item<bool>());
  EXPECT_TRUE(r.render.visible[1].item<bool>());
  EXPECT_FALSE(r.render.visible[2].item<bool>()) << "an indefinite covariance projects to an indefinite one";
  EXPECT_FALSE(r.render.visible[3].item<bool>());
  EXPECT_TRUE(r.render.visible[4].item<bool>());
  for (int64_t i : {2, 3}) EXPECT_EQ(r.grads[1][i].abs().sum().item<double>(), 0.0);
}

TEST(SplatStress, MeansBehindOnNearPlaneAndFarAway) {
  TestScene s = base_scene();
  s.camera.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  s.camera.near_plane = 0.1;
  set_row(s.gaussians.means, 0, {0.0, 0.0, -1.0});  // behind
  set_row(s.gaussians.means, 1, {0.0, 0.0, 0.1});   // exactly on the near plane: kept
  set_row(s.gaussians.means, 2, {0.0, 0.0, 0.0});   // at the camera centre
  set_row(s.gaussians.means, 3, {0.0, 0.0, 1e8});   // huge depth: a low-pass-sized dot
  set_row(s.gaussians.means, 4, {1e3, 0.0, 1.0});   // far outside the field of view
  set_row(s.gaussians.means, 5, {0.0, 0.0, 2e10});  // beyond the far plane
  const StressResult r = render_and_check(s);
  const std::vector<bool> expected{false, true, false, true, false, false};
  for (int64_t i = 0; i < 6; ++i) EXPECT_EQ(r.render.visible[i].item<bool>(), expected[i]) << "Gaussian " << i;
}

TEST(SplatStress, OpacityExactlyZeroAndOne) {
  TestScene s = base_scene();
  s.gaussians.opacities[0] = 0.0;
  s.gaussians.opacities[1] = 1.0;
  s.gaussians.opacities[2] = 1.0;
  const StressResult r = render_and_check(s);
  EXPECT_FALSE(r.render.visible[0].item<bool>());
  EXPECT_TRUE(r.render.visible[1].item<bool>());
  EXPECT_GT(r.grads[0][1].abs().sum().item<double>(), 0.0) << "the clamp zeroes only the centre pixels' gradient";
}

// Non-finite opacities are errors instead (test_splat_validation.cpp).
TEST(SplatStress, NonFiniteValuesCullOnlyTheirGaussian) {
  for (double bad : {kNaN, kInf, -kInf}) {
    for (const char* field : {"means", "scales", "rotations", "features"}) {
      TestScene s = base_scene();
      at::Tensor& t = std::string(field) == "means"       ? s.gaussians.means
                      : std::string(field) == "scales"    ? s.gaussians.scales
                      : std::string(field) == "rotations" ? s.gaussians.rotations
                                                          : s.gaussians.features;
      t.view({-1})[t.numel() / t.size(0) * 3] = bad;  // Gaussian 3's first entry
      const StressResult r = render_and_check(s);
      EXPECT_FALSE(r.render.visible[3].item<bool>()) << field << " = " << bad;
      EXPECT_TRUE(r.render.visible.sum().item<int64_t>() >= 6) << field << ": the others still render";
    }
  }
  SceneSpec spec;
  spec.covariances = true;
  TestScene s = random_scene(spec, 5);
  s.gaussians.covariances[2][1] = kNaN;
  const StressResult r = render_and_check(s);
  EXPECT_FALSE(r.render.visible[2].item<bool>());
  TestScene q = base_scene();
  set_row(q.gaussians.rotations, 0, {0, 0, 0, 0});  // a zero quaternion has no rotation
  EXPECT_FALSE(render_and_check(q).render.visible[0].item<bool>());
}

TEST(SplatStress, ThousandsOfGaussiansOnOnePixel) {
  const int64_t n = 5000;
  TestScene s = base_scene(n);
  s.camera = Camera::looking_forward(40.0, 9, 7);
  s.gaussians.means = at::tensor({0.0, 0.0, 2.0}, at::kDouble).repeat({n, 1}) + 1e-3 * at::randn({n, 3}, at::kDouble);
  s.gaussians.scales = at::full({n, 3}, 0.002, at::kDouble);
  const StressResult r = render_and_check(s);
  // Blending stops once T would drop below 1e-4; the last blended alpha is at most 0.7, so T ends in [1e-4, 1e-4 /
  // 0.3].
  EXPECT_NEAR(r.render.alpha[3][4].item<double>(), 1.0 - kMinTransmittance, 3e-4);
}

TEST(SplatStress, OneByOneAndHugeImages) {
  TestScene s = base_scene();
  s.camera = Camera::looking_forward(1.0, 1, 1);
  set_row(s.gaussians.means, 0, {0.0, 0.0, 3.0});
  const StressResult one = render_and_check(s);
  EXPECT_EQ(one.render.image.sizes(), at::IntArrayRef({1, 1, 3}));
  EXPECT_GT(one.render.alpha.item<double>(), 0.0);

  TestScene big = base_scene(200);
  for (auto& [name, t] : differentiable_inputs(big)) *t = t->to(at::kFloat);
  big.camera = Camera::looking_forward(4000.0, 4096, 4096);
  big.gaussians.means = big.gaussians.means * at::tensor({1.0f, 1.0f, 0.0f}) + at::tensor({0.0f, 0.0f, 3.0f});
  big.gaussians.scales = at::full({200, 3}, 0.004f);
  const StressResult r = render_and_check(big);
  EXPECT_EQ(r.render.image.sizes(), at::IntArrayRef({4096, 4096, 3}));
  EXPECT_GT(r.render.alpha.max().item<float>(), 0.5f);
}

// A CPU render whose Gaussians' tile rectangles add up to more than kCpuMaxTilePairs tiles is refused before any
// tile is tested: here 40 Gaussians of 1 km each cover all 1024 x 1024 tiles of a 16384 x 16384 image (a bound of
// 4.2e7 pairs); the refusal costs one projection pass. The 1000 Gaussians behind the camera do not count.
TEST(SplatStress, AbsurdCpuWorkloadIsRefusedBeforeBinning) {
  TestScene s = base_scene(1040);
  s.camera = Camera::looking_forward(8000.0, kMaxImageSide, kMaxImageSide);
  s.gaussians.means = at::tensor({0.0, 0.0, 3.0}, at::kDouble).repeat({1040, 1});
  s.gaussians.means.narrow(0, 40, 1000).select(1, 2).fill_(-3.0);
  s.gaussians.scales = at::full({1040, 3}, 1e3, at::kDouble);
  try {
    render(s.gaussians, s.background, s.camera);
    ADD_FAILURE() << "expected the CPU backend to refuse the render";
  } catch (const c10::Error& e) {
    const std::string message = e.what_without_backtrace();
    EXPECT_NE(message.find("sfgs::render (CPU): this image would need up to 4.2e+07 Gaussian-tile pairs (40 Gaussians "
                           "on screen, the largest covering 1024 x 1024 tiles), more than the CPU backend's limit of "
                           "3.4e+07; render on CUDA, use a smaller image, or check the scales"),
              std::string::npos)
        << message;
  }
}

}  // namespace
}  // namespace sfgs::testing
