// The splatting op's public C++ API (splat.h): cameras, the camera check, and render(), which calls the dispatcher
// operator of op.h.
#include "ops/splat/splat.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <utility>

#include <ATen/ATen.h>

#include "common/tensor_description.h"
#include "ops/splat/op.h"
#include "ops/splat/validation.h"
#include "ops/registration.h"
#include "ops/splat/constants.h"

namespace sfgs {

Camera Camera::from_tensor(const at::Tensor& world_to_camera, double fx, double fy, double cx, double cy, int64_t width,
                           int64_t height, double near_plane, double far_plane) {
  TORCH_CHECK(world_to_camera.defined() && world_to_camera.dim() == 2 && world_to_camera.size(0) == 4 &&
                  world_to_camera.size(1) == 4 && at::isFloatingType(world_to_camera.scalar_type()),
              "sfgs::Camera: world_to_camera must be a floating (4, 4) tensor, got ", describe(world_to_camera));
  const at::Tensor host = world_to_camera.detach().to(at::kCPU, at::kDouble).contiguous();
  Camera c;
  std::copy(host.data_ptr<double>(), host.data_ptr<double>() + 16, c.world_to_camera.begin());
  c.fx = fx;
  c.fy = fy;
  c.cx = cx;
  c.cy = cy;
  c.width = width;
  c.height = height;
  c.near_plane = near_plane;
  c.far_plane = far_plane;
  return c;
}

Camera Camera::looking_forward(double focal, int64_t width, int64_t height) {
  Camera c;
  c.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  c.fx = c.fy = focal;
  c.cx = 0.5 * double(width);
  c.cy = 0.5 * double(height);
  c.width = width;
  c.height = height;
  return c;
}

RenderResult render(const Gaussians& gaussians, const at::Tensor& background, const Camera& camera,
                    const RenderOptions& options) {
  // The op checks its arguments itself. render() computes, so it first refuses tensors the op would only describe
  // (meta), and it makes the one check the op leaves to the caller on CUDA, where it costs a device-to-host read.
  if (gaussians.means.defined()) splat::check_backend_device(gaussians.means);
  if (options.check_background && background.defined() && background.is_cuda())
    splat::check_background_finite(background);
  const bool dilate = options.low_pass || options.antialiased;
  const auto [image, alpha, depth, radii] = splat::render_gaussians(
      splat::SplatInputs{gaussians.means, gaussians.scales, gaussians.rotations, gaussians.covariances,
                         gaussians.opacities, gaussians.features, background},
      camera, dilate ? kLowPassVariancePx2 : 0.0, options.antialiased, options.deterministic, options.budget);
  return RenderResult{image, alpha, depth, radii, radii.select(1, 0) > 0};
}

std::array<double, 3> camera_centre(const Camera& camera) {
  const auto& m = camera.world_to_camera;
  std::array<double, 3> centre{};
  for (int i = 0; i < 3; ++i) centre[i] = -(m[0 * 4 + i] * m[3] + m[1 * 4 + i] * m[7] + m[2 * 4 + i] * m[11]);
  return centre;
}

bool camera_at_origin(const Camera& camera) {
  return camera.world_to_camera == std::array<double, 16>{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
}

std::string world_to_camera_problem(const std::array<double, 16>& m) {
  std::ostringstream why;
  for (double v : m)
    if (!std::isfinite(v)) {
      why << "world_to_camera must be finite, got an entry " << v;
      return why.str();
    }
  if (m[12] != 0 || m[13] != 0 || m[14] != 0 || m[15] != 1) {
    why << "the last row of world_to_camera must be (0, 0, 0, 1), got (" << m[12] << ", " << m[13] << ", " << m[14]
        << ", " << m[15] << ")";
    return why.str();
  }
  // The rotation block must be a proper rotation: R R^T = I within tolerance and det R = +1 (a singular, scaled or
  // mirroring matrix would project every point to the wrong place without any other sign of trouble).
  double deviation = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double dot = 0;
      for (int k = 0; k < 3; ++k) dot += m[size_t(4 * i + k)] * m[size_t(4 * j + k)];
      deviation = std::max(deviation, std::abs(dot - (i == j ? 1.0 : 0.0)));
    }
  const double det =
      m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8]) + m[2] * (m[4] * m[9] - m[5] * m[8]);
  if (deviation > kCameraRotationTolerance || det <= 0) {
    why << "the rotation part of world_to_camera must be orthonormal with determinant +1 (max |R R^T - I| <= "
        << kCameraRotationTolerance << "), got max |R R^T - I| = " << deviation << " and det R = " << det;
    return why.str();
  }
  return "";
}

std::string camera_problem(const Camera& c) {
  if (std::string problem = world_to_camera_problem(c.world_to_camera); !problem.empty()) return problem;
  std::ostringstream why;
  if (!std::isfinite(c.fx) || !std::isfinite(c.fy) || !(c.fx > 0) || !(c.fy > 0)) {
    why << "focal lengths must be finite and positive, got fx = " << c.fx << ", fy = " << c.fy;
    return why.str();
  }
  if (!std::isfinite(c.cx) || !std::isfinite(c.cy)) {
    why << "the principal point must be finite, got (" << c.cx << ", " << c.cy << ")";
    return why.str();
  }
  if (c.width < 1 || c.height < 1 || c.width > kMaxImageSide || c.height > kMaxImageSide) {
    why << "image sides must be in [1, " << kMaxImageSide << "], got " << c.width << " x " << c.height;
    return why.str();
  }
  if (!std::isfinite(c.near_plane) || !(c.near_plane > 0)) {
    why << "near_plane must be finite and positive, got " << c.near_plane;
    return why.str();
  }
  if (!(c.far_plane > c.near_plane)) {
    why << "far_plane must exceed near_plane (" << c.near_plane << "), got " << c.far_plane;
    return why.str();
  }
  return "";
}

bool cuda_backend_available() { return ops::kBuiltWithCuda; }

}  // namespace sfgs
