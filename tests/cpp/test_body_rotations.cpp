// Rotation utilities (csrc/body/rotations.h): conventions, round trips, accuracy near 0 and pi, gradients at 0.
#include <cmath>

#include <gtest/gtest.h>

#include "body/rotations.h"
#include "test_body_utils.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using body::axis_angle_to_matrix;
using body::matrix_to_axis_angle;
using body::matrix_to_rotation_6d;
using body::rotation_6d_to_matrix;

// Axis-angle vectors with angles spread over [0, pi), plus tiny ones.
at::Tensor sample_axis_angles(int64_t n, uint64_t seed) {
  at::manual_seed(seed);
  const at::Tensor axis = at::randn({n, 3}, at::kDouble);
  at::Tensor angle = at::rand({n, 1}, at::kDouble) * (M_PI - 1e-3);
  angle.narrow(0, 0, 4).copy_(at::tensor({0.0, 1e-9, 1e-4, 0.09}, at::kDouble).view({4, 1}));
  return axis / axis.norm(2, 1, true) * angle;
}

TEST(BodyRotations, RightHandedAxisAngle) {
  const at::Tensor r = axis_angle_to_matrix(at::tensor({0.0, 0.0, M_PI / 2}, at::kDouble));
  EXPECT_LT(
      max_difference(r.matmul(at::tensor({1.0, 0.0, 0.0}, at::kDouble)), at::tensor({0.0, 1.0, 0.0}, at::kDouble)),
      1e-15);
  EXPECT_TRUE(
      axis_angle_to_matrix(at::zeros({2, 5, 3}, at::kDouble)).equal(at::eye(3, at::kDouble).expand({2, 5, 3, 3})));
}

TEST(BodyRotations, MatricesAreRotationsAndAgreeWithTheExponential) {
  const at::Tensor aa = sample_axis_angles(200, 1);
  const at::Tensor r = axis_angle_to_matrix(aa);
  const at::Tensor eye = at::eye(3, at::kDouble);
  EXPECT_LT(max_difference(r.matmul(r.transpose(-1, -2)), eye.expand_as(r)), 1e-14);
  EXPECT_LT(max_difference(at::linalg_det(r), at::ones({200}, at::kDouble)), 1e-14);
  // exp([v]x) by a long Taylor series, independent of Rodrigues' formula.
  const at::Tensor x = aa.select(1, 0), y = aa.select(1, 1), z = aa.select(1, 2), zero = at::zeros_like(x);
  const at::Tensor k = at::stack({zero, -z, y, z, zero, -x, -y, x, zero}, 1).view({-1, 3, 3});
  at::Tensor term = eye.expand_as(k).clone(), series = term.clone();
  for (int n = 1; n < 40; ++n) {
    term = term.matmul(k) / n;
    series = series + term;
  }
  EXPECT_LT(max_difference(r, series), 1e-14);
}

TEST(BodyRotations, AxisAngleRoundTripsIncludingNearZeroAndPi) {
  at::Tensor aa = sample_axis_angles(300, 2);
  EXPECT_LT(max_difference(matrix_to_axis_angle(axis_angle_to_matrix(aa)), aa), 1e-12);
  // Near pi the axis is recovered up to sign, the angle exactly.
  const at::Tensor axis = at::tensor({0.3, -0.5, 0.8}, at::kDouble) / std::sqrt(0.98);
  for (double angle : {M_PI - 1e-6, M_PI}) {
    const at::Tensor back = matrix_to_axis_angle(axis_angle_to_matrix(axis * angle));
    EXPECT_NEAR(back.norm().item<double>(), angle, 1e-9);
    EXPECT_NEAR(std::abs(back.dot(axis).item<double>()), angle, 1e-9);
  }
  // float32 stays accurate too.
  const at::Tensor f = aa.to(at::kFloat);
  EXPECT_LT(max_difference(matrix_to_axis_angle(axis_angle_to_matrix(f)).to(at::kDouble), aa), 2e-5);
}

// The rotation of a unit quaternion (w, x, y, z), written out.
at::Tensor quaternion_to_matrix(const at::Tensor& q) {
  const at::Tensor w = q.select(-1, 0), x = q.select(-1, 1), y = q.select(-1, 2), z = q.select(-1, 3);
  return at::stack({1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y), 2 * (x * y + w * z),
                    1 - 2 * (x * x + z * z), 2 * (y * z - w * x), 2 * (x * z - w * y), 2 * (y * z + w * x),
                    1 - 2 * (x * x + y * y)},
                   -1)
      .view({-1, 3, 3});
}

TEST(BodyRotations, QuaternionsOfEveryRotationIncludingHalfTurns) {
  // Half turns about the axes and a diagonal (where w = 0 and a sign test on the off-diagonal differences gives
  // 0), the identity, a near-identity and random rotations.
  const double s = std::sqrt(0.5);
  at::Tensor aa = at::cat({at::tensor({M_PI, 0.0, 0.0, 0.0, M_PI, 0.0, 0.0, 0.0, M_PI, M_PI * s, M_PI * s, 0.0, 0.0,
                                       0.0, 0.0, 1e-9, 0.0, 0.0},
                                      at::kDouble)
                               .view({-1, 3}),
                           sample_axis_angles(200, 9)});
  const at::Tensor r = axis_angle_to_matrix(aa);
  const at::Tensor q = body::matrix_to_quaternion(r);
  EXPECT_LT((q.norm(2, -1) - 1).abs().max().item<double>(), 1e-12);
  EXPECT_GE(q.select(-1, 0).min().item<double>(), 0.0);
  EXPECT_LT(max_difference(quaternion_to_matrix(q), r), 1e-12);
  // The eigenvector frames of an export: a proper rotation whose columns came out flipped in pairs.
  const at::Tensor flipped = r * at::tensor({-1.0, -1.0, 1.0}, at::kDouble);
  EXPECT_LT(max_difference(quaternion_to_matrix(body::matrix_to_quaternion(flipped)), flipped), 1e-12);
  expect_error([] { body::matrix_to_quaternion(at::zeros({4, 3})); }, {"matrix"});
}

TEST(BodyRotations, SixDIsTheFirstTwoRowsAndRoundTrips) {
  const at::Tensor r = axis_angle_to_matrix(sample_axis_angles(50, 3));
  const at::Tensor six = matrix_to_rotation_6d(r);
  EXPECT_TRUE(six.narrow(-1, 0, 3).equal(r.select(-2, 0)));
  EXPECT_TRUE(six.narrow(-1, 3, 3).equal(r.select(-2, 1)));
  EXPECT_LT(max_difference(rotation_6d_to_matrix(six), r), 1e-14);
  // Any two independent vectors give a rotation whose first row points along the first.
  const at::Tensor raw = at::randn({50, 6}, at::kDouble) * 3;
  const at::Tensor m = rotation_6d_to_matrix(raw);
  EXPECT_LT(max_difference(m.matmul(m.transpose(-1, -2)), at::eye(3, at::kDouble).expand_as(m)), 1e-14);
  EXPECT_LT(max_difference(at::linalg_det(m), at::ones({50}, at::kDouble)), 1e-14);
  EXPECT_LT(max_difference(m.select(-2, 0), raw.narrow(-1, 0, 3) / raw.narrow(-1, 0, 3).norm(2, -1, true)), 1e-14);
}

TEST(BodyRotations, GradientsAreFiniteAndCorrectAtZeroAndBeyond) {
  const at::Tensor weights = at::randn({3, 3}, at::kDouble);
  for (const at::Tensor& start :
       {at::zeros({3}, at::kDouble), at::tensor({1e-5, -2e-5, 0.0}, at::kDouble),
        at::tensor({0.05, 0.02, -0.07}, at::kDouble), at::tensor({0.7, -1.1, 0.4}, at::kDouble)}) {
    const at::Tensor v = start.clone().requires_grad_(true);
    (axis_angle_to_matrix(v) * weights).sum().backward();
    const at::Tensor grad = v.grad();
    ASSERT_TRUE(at::isfinite(grad).all().item<bool>());
    const at::Tensor x = start.clone();
    for (int64_t i = 0; i < 3; ++i) {
      const double fd =
          central_difference([&] { return (axis_angle_to_matrix(x) * weights).sum().item<double>(); }, x, i, 1e-6);
      EXPECT_NEAR(grad[i].item<double>(), fd, 1e-8) << "at " << start << " component " << i;
    }
  }
  // The inverse is differentiable too (its gradient closes the loop: d/dv of log(exp(v)) is the identity).
  const at::Tensor v = at::tensor({0.3, -0.2, 0.5}, at::kDouble).requires_grad_(true);
  const at::Tensor back = matrix_to_axis_angle(axis_angle_to_matrix(v));
  for (int64_t i = 0; i < 3; ++i) {
    const at::Tensor g = torch::autograd::grad({back[i]}, {v}, {}, /*retain_graph=*/true)[0];
    EXPECT_LT(max_difference(g, at::one_hot(at::tensor(i), 3).to(at::kDouble).view({3})), 1e-12);
  }
}

TEST(BodyRotations, ShapesAreChecked) {
  expect_error(
      [] {
        axis_angle_to_matrix(at::zeros({4, 2}));
      },
      {"axis_angle must be a floating tensor of shape (..., 3), got a Float tensor of shape [4, 2]"});
  expect_error([] { matrix_to_axis_angle(at::zeros({4, 3}, at::kLong)); }, {"matrix must be a floating tensor"});
  expect_error([] { rotation_6d_to_matrix(at::zeros({5})); }, {"rotation_6d", "[5]"});
}

}  // namespace
}  // namespace sfgs::testing
