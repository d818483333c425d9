// The shared per-Gaussian and per-pair math on its own: the tile test is conservative and tight, covariances
// built from scale and rotation are what they should be, and their gradient matches finite differences.
#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "ops/splat/pair_math.h"
#include "ops/splat/constants.h"

namespace sfgs::splat {
namespace {

double sigma_at(const ProjectedGaussian<double>& g, double x, double y) {
  const double dx = x - g.mean[0], dy = y - g.mean[1];
  return 0.5 * (g.conic[0] * dx * dx + g.conic[2] * dy * dy) + g.conic[1] * dx * dy;
}

ProjectedGaussian<double> random_projected(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  // Random SPD 2x2 covariance with axes up to 30 px and any orientation.
  const double s1 = 0.5 + 30 * u(rng), s2 = 0.5 + 30 * u(rng), t = 3.14159 * u(rng);
  const double c = std::cos(t), s = std::sin(t);
  const double a = c * c * s1 * s1 + s * s * s2 * s2, b = c * s * (s1 * s1 - s2 * s2),
               d = s * s * s1 * s1 + c * c * s2 * s2;
  const double det = a * d - b * b;
  ProjectedGaussian<double> g;
  g.mean = Vec2<double>(-20 + 140 * u(rng), -20 + 120 * u(rng));
  g.conic = Vec3<double>(d / det, -b / det, a / det);
  g.opacity = 0.01 + 0.98 * u(rng);
  g.depth = 1.0;
  g.level = std::log(g.opacity / kMinAlpha);
  return g;
}

TEST(PairMath, TileTestIsConservativeAndTight) {
  std::mt19937 rng(3);
  const int width = 100, height = 80;
  int touched = 0, with_pixel = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const ProjectedGaussian<double> g = random_projected(rng);
    for (int ty = 0; ty < (height + kTileSize - 1) / kTileSize; ++ty)
      for (int tx = 0; tx < (width + kTileSize - 1) / kTileSize; ++tx) {
        double min_pixel = 1e300, min_dense = 1e300;
        for (int y = ty * kTileSize; y < std::min(height, (ty + 1) * kTileSize); ++y)
          for (int x = tx * kTileSize; x < std::min(width, (tx + 1) * kTileSize); ++x)
            min_pixel = std::min(min_pixel, sigma_at(g, x + kPixelCentre, y + kPixelCentre));
        // Dense sampling of the rectangle spanned by the tile's pixel centres.
        const double x0 = tx * kTileSize + kPixelCentre, y0 = ty * kTileSize + kPixelCentre;
        const double x1 = std::min(width, (tx + 1) * kTileSize) - 1 + kPixelCentre;
        const double y1 = std::min(height, (ty + 1) * kTileSize) - 1 + kPixelCentre;
        for (int i = 0; i <= 64; ++i)
          for (int j = 0; j <= 64; ++j)
            min_dense = std::min(min_dense, sigma_at(g, x0 + (x1 - x0) * i / 64.0, y0 + (y1 - y0) * j / 64.0));
        const bool touches = tile_touches(g, tx, ty, width, height);
        if (min_pixel <= g.level) {
          EXPECT_TRUE(touches) << "a pixel with alpha >= 1/255 lies in a tile the test rejected";
          ++with_pixel;
        }
        if (touches) {
          ++touched;
          EXPECT_LE(min_dense, g.level * (1 + 2 * kTileTestSlack) + 1e-3) << "the tile test accepted a far tile";
        }
      }
  }
  EXPECT_GT(with_pixel, 1000);
  EXPECT_LE(touched, with_pixel * 1.1) << "the test should be nearly exact at pixel resolution";
}

TEST(PairMath, CovarianceFromScaleRotationIsRSSRt) {
  const Vec3<double> scale(0.1, 0.2, 0.3);
  const double half = 0.5 * 0.7;  // 0.7 rad about z
  Mat3<double> cov;
  ASSERT_TRUE(covariance_from_scale_rotation(scale, Vec4<double>(2 * std::cos(half), 0, 0, 2 * std::sin(half)), cov));
  const double c = std::cos(0.7), s = std::sin(0.7);
  EXPECT_NEAR(cov[0][0], c * c * 0.01 + s * s * 0.04, 1e-15);
  EXPECT_NEAR(cov[1][0], c * s * (0.01 - 0.04), 1e-15);
  EXPECT_NEAR(cov[2][2], 0.09, 1e-15);
  EXPECT_EQ(cov[1][0], cov[0][1]);
  EXPECT_FALSE(covariance_from_scale_rotation(scale, Vec4<double>(0, 0, 0, 0), cov));
  EXPECT_FALSE(covariance_from_scale_rotation(Vec3<double>(NAN, 0, 0), Vec4<double>(1, 0, 0, 0), cov));
}

TEST(PairMath, CovarianceGradientMatchesFiniteDifferences) {
  const Vec3<double> scale(0.1, 0.25, 0.05);
  const Vec4<double> quat(0.9, -0.3, 0.5, 0.2);  // deliberately not unit length
  Mat3<double> weights;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) weights[i][j] = weights[j][i] = 0.3 * (i + 1) - 0.7 * j + 0.1 * i * j;
  const auto loss = [&](const Vec3<double>& s, const Vec4<double>& q) {
    Mat3<double> cov;
    covariance_from_scale_rotation(s, q, cov);
    double total = 0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) total += weights[i][j] * cov[i][j];
    return total;
  };
  Vec3<double> grad_scale;
  Vec4<double> grad_quat;
  covariance_from_scale_rotation_vjp(scale, quat, weights, grad_scale, grad_quat);
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Vec3<double> p = scale, m = scale;
    p[k] += h;
    m[k] -= h;
    EXPECT_NEAR(grad_scale[k], (loss(p, quat) - loss(m, quat)) / (2 * h), 1e-8) << "scale " << k;
  }
  for (int k = 0; k < 4; ++k) {
    Vec4<double> p = quat, m = quat;
    p[k] += h;
    m[k] -= h;
    EXPECT_NEAR(grad_quat[k], (loss(scale, p) - loss(scale, m)) / (2 * h), 1e-8) << "quaternion " << k;
  }
}

TEST(PairMath, PairAlphaClampsAndSkips) {
  ProjectedGaussian<double> g;
  g.mean = Vec2<double>(10.5, 10.5);
  g.conic = Vec3<double>(1.0, 0.0, 1.0);
  g.opacity = 1.0;
  g.level = std::log(1.0 / kMinAlpha);
  PairAlpha<double> p;
  ASSERT_TRUE(pair_alpha(g, 10.5, 10.5, p));
  EXPECT_EQ(p.alpha, kMaxAlpha);
  EXPECT_TRUE(p.clamped);
  EXPECT_FALSE(pair_alpha(g, 14.5, 10.5, p)) << "exp(-8) < 1/255";
  ASSERT_TRUE(pair_alpha(g, 11.5, 10.5, p));
  EXPECT_NEAR(p.alpha, std::exp(-0.5), 1e-15);
  EXPECT_FALSE(p.clamped);
}

}  // namespace
}  // namespace sfgs::splat
