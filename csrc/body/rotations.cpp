#include "body/rotations.h"

#include <iterator>
#include <string>
#include <vector>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <ATen/core/grad_mode.h>

#include "body/body_backend.h"
#include "body/tensor_checks.h"
#include "common/constants.h"
#include "body/constants.h"

namespace sfgs::body {
namespace {

void check_last_dims(const at::Tensor& t, const char* function, const char* name, at::IntArrayRef last) {
  const int64_t n = static_cast<int64_t>(last.size());
  bool ok = t.defined() && t.dim() >= n && at::isFloatingType(t.scalar_type());
  for (int64_t i = 0; ok && i < n; ++i) ok = t.size(t.dim() - n + i) == last[i];
  std::string expected;
  for (int64_t d : last) expected += ", " + std::to_string(d);
  TORCH_CHECK(ok, function, ": ", name, " must be a floating tensor of shape (...", expected, "), got ", describe(t));
}

// Horner evaluation of sum_k coefficients[k] * x^k.
at::Tensor polynomial(const at::Tensor& x, std::initializer_list<double> coefficients) {
  at::Tensor result;
  for (auto c = std::rbegin(coefficients); c != std::rend(coefficients); ++c)
    result = result.defined() ? result * x + *c : at::full_like(x, *c);
  return result;
}

}  // namespace

at::Tensor axis_angle_to_matrix(const at::Tensor& axis_angle) {
  check_last_dims(axis_angle, "axis_angle_to_matrix", "axis_angle", {3});
  const bool fused = axis_angle.is_cuda() && axis_angle.scalar_type() == at::kFloat &&
                     !(axis_angle.requires_grad() && at::GradMode::is_enabled()) && cuda::available();
  if (!fused) return axis_angle_to_matrix_reference(axis_angle);
  const at::Tensor input = axis_angle.contiguous();
  std::vector<int64_t> shape = axis_angle.sizes().vec();
  shape.push_back(3);
  at::Tensor matrices = at::empty(shape, input.options());
  AxisAngleArrays arrays{};
  arrays.axis_angle = input.data_ptr<float>();
  arrays.count = input.numel() / 3;
  arrays.series_angle = static_cast<float>(kRotationSeriesAngle);
  arrays.matrices = matrices.data_ptr<float>();
  cuda::axis_angle_to_matrix(arrays, input.device());
  return matrices;
}

at::Tensor axis_angle_to_matrix_reference(const at::Tensor& axis_angle) {
  check_last_dims(axis_angle, "axis_angle_to_matrix", "axis_angle", {3});
  const at::Tensor theta2 = (axis_angle * axis_angle).sum(-1, /*keepdim=*/true).unsqueeze(-1);  // (..., 1, 1)
  // Rodrigues: R = I + a K + b K^2 with a = sin(t)/t and b = (1 - cos t)/t^2 = 0.5 (sin(t/2)/(t/2))^2, which
  // has no cancellation. Near zero both are even series in t; the other branch sees a safe angle so that no
  // NaN gradient leaks through the selection.
  const at::Tensor small = theta2 < kRotationSeriesAngle * kRotationSeriesAngle;
  const at::Tensor theta = at::where(small, at::ones_like(theta2), theta2).sqrt();
  const at::Tensor half_sinc = (0.5 * theta).sin() / (0.5 * theta);
  const at::Tensor a =
      at::where(small, polynomial(theta2, {1.0, -1.0 / 6, 1.0 / 120, -1.0 / 5040, 1.0 / 362880}), theta.sin() / theta);
  const at::Tensor b = at::where(small, polynomial(theta2, {0.5, -1.0 / 24, 1.0 / 720, -1.0 / 40320, 1.0 / 3628800}),
                                 0.5 * half_sinc * half_sinc);
  const at::Tensor x = axis_angle.select(-1, 0), y = axis_angle.select(-1, 1), z = axis_angle.select(-1, 2);
  const at::Tensor zero = at::zeros_like(x);
  const at::Tensor k = at::stack({zero, -z, y, z, zero, -x, -y, x, zero}, -1).unflatten(-1, {3, 3});
  const at::Tensor eye = at::eye(3, axis_angle.options());
  // K^2 = v v^T - t^2 I.
  const at::Tensor k2 = axis_angle.unsqueeze(-1) * axis_angle.unsqueeze(-2) - theta2 * eye;
  return eye + a * k + b * k2;
}

at::Tensor matrix_to_quaternion(const at::Tensor& matrix) {
  check_last_dims(matrix, "matrix_to_quaternion", "matrix", {3, 3});
  const auto m = [&](int64_t r, int64_t c) { return matrix.select(-2, r).select(-1, c); };
  // Four scaled copies of the quaternion, each computed from a different diagonal combination; the one with the
  // largest pivot (4 w^2, 4 x^2, 4 y^2 or 4 z^2) is well conditioned for every rotation (Shepperd's method), 180
  // degrees included, where w and the differences of the off-diagonal pairs vanish.
  const at::Tensor tw = 1 + m(0, 0) + m(1, 1) + m(2, 2), tx = 1 + m(0, 0) - m(1, 1) - m(2, 2);
  const at::Tensor ty = 1 - m(0, 0) + m(1, 1) - m(2, 2), tz = 1 - m(0, 0) - m(1, 1) + m(2, 2);
  const at::Tensor c21 = m(2, 1) - m(1, 2), c02 = m(0, 2) - m(2, 0), c10 = m(1, 0) - m(0, 1);
  const at::Tensor s10 = m(1, 0) + m(0, 1), s02 = m(0, 2) + m(2, 0), s21 = m(2, 1) + m(1, 2);
  const at::Tensor candidates = at::stack({at::stack({tw, c21, c02, c10}, -1), at::stack({c21, tx, s10, s02}, -1),
                                           at::stack({c02, s10, ty, s21}, -1), at::stack({c10, s02, s21, tz}, -1)},
                                          -2);  // (..., 4, 4)
  const at::Tensor best = at::stack({tw, tx, ty, tz}, -1).argmax(-1, /*keepdim=*/true);
  const at::Tensor pick = (at::arange(4, best.options()) == best).to(candidates.scalar_type()).unsqueeze(-1);
  const at::Tensor q = (candidates * pick).sum(-2);
  // q and -q are the same rotation; w >= 0 puts the angle in [0, pi]. The pivot is at least 1 for a rotation, so
  // the norm is too.
  const at::Tensor sign = 1 - 2 * (q.narrow(-1, 0, 1) < 0).to(q.scalar_type());
  return q * (sign / q.norm(2, -1, /*keepdim=*/true).clamp_min(kMinQuaternionNorm));
}

at::Tensor matrix_to_axis_angle(const at::Tensor& matrix) {
  check_last_dims(matrix, "matrix_to_axis_angle", "matrix", {3, 3});
  const at::Tensor q = matrix_to_quaternion(matrix);
  const at::Tensor w = q.select(-1, 0).unsqueeze(-1);
  const at::Tensor xyz = q.narrow(-1, 1, 3);
  const at::Tensor n2 = (xyz * xyz).sum(-1, /*keepdim=*/true);
  // angle / n = 2 atan2(n, w) / n; for small angles 2 atan(r)/(r w) with r = n / w, as a series in r^2.
  const double half_limit = 0.5 * kRotationSeriesAngle;
  const at::Tensor small = n2 < half_limit * half_limit;
  const at::Tensor safe_n = at::where(small, at::ones_like(n2), n2).sqrt();
  const at::Tensor safe_w = at::where(small, w, at::ones_like(w));
  const at::Tensor r2 = n2 / (safe_w * safe_w);
  const at::Tensor series = 2.0 / safe_w * polynomial(r2, {1.0, -1.0 / 3, 1.0 / 5, -1.0 / 7, 1.0 / 9});
  const at::Tensor factor = at::where(small, series, 2.0 * at::atan2(safe_n, w) / safe_n);
  return xyz * factor;
}

at::Tensor matrix_to_rotation_6d(const at::Tensor& matrix) {
  check_last_dims(matrix, "matrix_to_rotation_6d", "matrix", {3, 3});
  return matrix.narrow(-2, 0, 2).flatten(-2);
}

at::Tensor rotation_6d_to_matrix(const at::Tensor& rotation_6d) {
  check_last_dims(rotation_6d, "rotation_6d_to_matrix", "rotation_6d", {6});
  const auto normalized = [](const at::Tensor& v) {
    return v / v.norm(2, -1, /*keepdim=*/true).clamp_min(kMinRotation6dNorm);
  };
  const at::Tensor a1 = rotation_6d.narrow(-1, 0, 3), a2 = rotation_6d.narrow(-1, 3, 3);
  const at::Tensor b1 = normalized(a1);
  const at::Tensor b2 = normalized(a2 - (b1 * a2).sum(-1, /*keepdim=*/true) * b1);
  const at::Tensor b3 = at::linalg_cross(b1, b2, -1);
  return at::stack({b1, b2, b3}, -2);
}

}  // namespace sfgs::body
