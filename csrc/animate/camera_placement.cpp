#include "animate/camera_placement.h"

#include <cmath>

#include <ATen/ATen.h>

namespace sfgs::animate {

Camera look_at_camera(const Camera& lens, const std::array<double, 3>& eye, const std::array<double, 3>& target) {
  double fwd[3] = {target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]};
  const double fn = std::sqrt(fwd[0] * fwd[0] + fwd[1] * fwd[1] + fwd[2] * fwd[2]);
  TORCH_CHECK(fn > 0, "the camera distance must be positive");
  for (double& v : fwd) v /= fn;
  double right[3] = {-fwd[2], 0.0, fwd[0]};  // fwd x (0, 1, 0)
  const double rn = std::sqrt(right[0] * right[0] + right[2] * right[2]);
  TORCH_CHECK(rn > 0, "the camera looks straight up or down (its height is its whole distance)");
  right[0] /= rn;
  right[2] /= rn;
  const double down[3] = {fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2],
                          fwd[0] * right[1] - fwd[1] * right[0]};
  const double* rows[3] = {right, down, fwd};
  Camera cam = lens;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam.world_to_camera[size_t(4 * r + c)] = rows[r][c];
    cam.world_to_camera[size_t(4 * r + 3)] = -(rows[r][0] * eye[0] + rows[r][1] * eye[1] + rows[r][2] * eye[2]);
  }
  return cam;
}

Camera orbit_camera(const Camera& base, const std::array<double, 3>& centre, double angle) {
  const std::array<double, 3> e = camera_centre(base);
  const double radius = std::hypot(e[0] - centre[0], e[2] - centre[2]);
  const double a = std::atan2(e[0] - centre[0], e[2] - centre[2]) + angle;
  return look_at_camera(base, {centre[0] + radius * std::sin(a), e[1], centre[2] + radius * std::cos(a)}, centre);
}

Camera camera_in_front(const Camera& lens, const std::array<double, 3>& target, double distance, double height,
                       double angle) {
  const std::array<double, 3> eye{target[0] + distance * std::sin(angle), target[1] + height,
                                  target[2] + distance * std::cos(angle)};
  return look_at_camera(lens, eye, target);
}

std::array<double, 3> centre_of(const model::AvatarOutput& posed) {
  const at::Tensor points = posed.means.detach();
  const at::Tensor c = ((std::get<0>(points.min(0)) + std::get<0>(points.max(0))) / 2).cpu().to(at::kDouble);
  return {c[0].item<double>(), c[1].item<double>(), c[2].item<double>()};
}

}  // namespace sfgs::animate
