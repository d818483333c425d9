#include "splat/camera_frame.h"

#include <ATen/ATen.h>

#include "common/tensor_description.h"

namespace sfgs {
namespace {

// The upper triangle of a symmetric 3x3 matrix in the splatting op's order: xx, xy, xz, yy, yz, zz.
constexpr int kCovariancePairs[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};

}  // namespace

void write_camera_frame(const Camera& camera, float* out) {
  const auto r = [&](int row, int column) { return camera.world_to_camera[size_t(4 * row + column)]; };
  for (int row = 0; row < 3; ++row)
    for (int column = 0; column < 3; ++column) *out++ = float(r(row, column));
  for (int row = 0; row < 3; ++row) *out++ = float(r(row, 3));
  // Row (a, b), column (i, j) of the covariance map: R_ai R_bj + R_aj R_bi (one term when i == j).
  for (int k = 0; k < 6; ++k) {
    const int a = kCovariancePairs[k][0], b = kCovariancePairs[k][1];
    for (int l = 0; l < 6; ++l) {
      const int i = kCovariancePairs[l][0], j = kCovariancePairs[l][1];
      double value = r(a, i) * r(b, j);
      if (i != j) value += r(a, j) * r(b, i);
      *out++ = float(value);
    }
  }
}

CameraFrame::CameraFrame(const at::Tensor& values) {
  TORCH_CHECK(values.dim() == 1 && values.size(0) == kCameraFrameValues && at::isFloatingType(values.scalar_type()),
              "CameraFrame: a floating (", kCameraFrameValues, ") tensor of write_camera_frame's values expected, got ",
              describe(values));
  rotation = values.narrow(0, 0, kCameraFrameRotationValues).view({3, 3});
  translation = values.narrow(0, kCameraFrameRotationValues, kCameraFrameTranslationValues);
  covariance_map =
      values.narrow(0, kCameraFrameRotationValues + kCameraFrameTranslationValues, kCameraFrameCovarianceValues)
          .view({6, 6});
}

at::Tensor CameraFrame::points(const at::Tensor& points) const {
  return at::addmm(translation.unsqueeze(0), points, rotation.t());
}

at::Tensor CameraFrame::directions(const at::Tensor& directions) const { return directions.matmul(rotation.t()); }

at::Tensor CameraFrame::covariances(const at::Tensor& covariances) const {
  return covariances.matmul(covariance_map.t());
}

Camera camera_at_origin_of(Camera camera) {
  camera.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  return camera;
}

Camera with_centred_principal_point(Camera camera) {
  // u = fx x / z + cx = fx (x + (cx - cx') z / fx) / z + cx': the depth row, scaled, added to the x row (y alike).
  const double centre_x = 0.5 * double(camera.width), centre_y = 0.5 * double(camera.height);
  const double shear_x = (camera.cx - centre_x) / camera.fx, shear_y = (camera.cy - centre_y) / camera.fy;
  auto& m = camera.world_to_camera;
  for (int column = 0; column < 4; ++column) {
    m[size_t(column)] += shear_x * m[size_t(8 + column)];
    m[size_t(4 + column)] += shear_y * m[size_t(8 + column)];
  }
  camera.cx = centre_x;
  camera.cy = centre_y;
  return camera;
}

}  // namespace sfgs
