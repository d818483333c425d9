#include "ops/splat/camera_frame.h"

#include <utility>
#include <vector>

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

namespace {

// world_to_camera's rotation (3, 3) and translation (3) with the options of `like`.
std::pair<at::Tensor, at::Tensor> placement(const Camera& camera, const at::Tensor& like) {
  const auto& m = camera.world_to_camera;
  const at::Tensor view =
      at::tensor(std::vector<double>(m.begin(), m.end()), at::kDouble).view({4, 4}).to(like.options());
  return {view.slice(0, 0, 3).slice(1, 0, 3), view.slice(0, 0, 3).select(1, 3)};
}

}  // namespace

at::Tensor points_in_camera_frame(const at::Tensor& points, const Camera& camera) {
  if (camera_at_origin(camera)) return points;
  const auto [rotation, translation] = placement(camera, points);
  return points.matmul(rotation.t()) + translation;
}

at::Tensor directions_in_camera_frame(const at::Tensor& directions, const Camera& camera) {
  if (camera_at_origin(camera)) return directions;
  return directions.matmul(placement(camera, directions).first.t());
}

PixelView pixel_view(const at::Tensor& camera_points, const Camera& camera) {
  TORCH_CHECK(camera_points.dim() == 2 && camera_points.size(1) == 3, "pixel_view: points (N, 3) expected, got ",
              describe(camera_points));
  const at::Tensor z = camera_points.select(1, 2);
  PixelView view;
  view.depth = z.clamp_min(camera.near_plane);
  view.u = camera.fx * camera_points.select(1, 0) / view.depth + camera.cx;
  view.v = camera.fy * camera_points.select(1, 1) / view.depth + camera.cy;
  view.inside = (z > camera.near_plane) & (view.u >= 0) & (view.u < double(camera.width)) & (view.v >= 0) &
                (view.v < double(camera.height));
  return view;
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

namespace {

void check_shapes(const CameraTensors& c) {
  const at::Tensor& m = c.world_to_camera;
  TORCH_CHECK(m.defined() && m.dim() == 2 && m.size(0) == 4 && m.size(1) == 4 && at::isFloatingType(m.scalar_type()),
              "camera: world_to_camera must be a floating (4, 4) tensor, got ", describe(m));
  const at::Tensor& k = c.intrinsics;
  TORCH_CHECK(k.defined() && k.dim() == 1 && k.size(0) == 4 && at::isFloatingType(k.scalar_type()),
              "camera: intrinsics must be a floating (4) tensor (fx, fy, cx, cy), got ", describe(k));
}

}  // namespace

Camera CameraTensors::value() const {
  check_shapes(*this);
  const at::Tensor k = intrinsics.detach().to(at::kCPU, at::kDouble).contiguous();
  const double* v = k.data_ptr<double>();
  return Camera::from_tensor(world_to_camera.detach(), v[0], v[1], v[2], v[3], width, height, near_plane, far_plane);
}

namespace {

// (N, 3, 3) rotation matrices of quaternions (N, 4: w, x, y, z), normalised here.
at::Tensor rotation_matrices(const at::Tensor& quaternions) {
  const at::Tensor q = quaternions / quaternions.norm(2, 1, true);
  const at::Tensor w = q.select(1, 0), x = q.select(1, 1), y = q.select(1, 2), z = q.select(1, 3);
  return at::stack({1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),  //
                    2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),  //
                    2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)},
                   1)
      .view({-1, 3, 3});
}

// Packed covariances (N, 6) as (N, 3, 3) matrices and back, in kCovariancePairs' order.
at::Tensor unpacked(const at::Tensor& packed) {
  std::vector<int64_t> index(9);
  for (int k = 0; k < 6; ++k) {
    const int a = kCovariancePairs[k][0], b = kCovariancePairs[k][1];
    index[size_t(3 * a + b)] = index[size_t(3 * b + a)] = k;
  }
  return packed.index_select(1, at::tensor(index, packed.options().dtype(at::kLong))).view({-1, 3, 3});
}
at::Tensor packed(const at::Tensor& matrices) {
  std::vector<int64_t> index;
  for (const auto& pair : kCovariancePairs) index.push_back(3 * pair[0] + pair[1]);
  return matrices.reshape({-1, 9}).index_select(1, at::tensor(index, matrices.options().dtype(at::kLong)));
}

}  // namespace

Gaussians seen_from(const Gaussians& gaussians, const CameraTensors& camera) {
  check_shapes(camera);
  const at::Tensor& means = gaussians.means;
  TORCH_CHECK(means.defined() && means.dim() == 2 && means.size(1) == 3, "seen_from: means must be (N, 3), got ",
              describe(means));
  const int64_t n = means.size(0);
  const at::Tensor& given = gaussians.covariances;
  TORCH_CHECK(given.defined() ? given.sizes() == at::IntArrayRef({n, 6})
                              : gaussians.scales.defined() && gaussians.rotations.defined() &&
                                    gaussians.scales.sizes() == at::IntArrayRef({n, 3}) &&
                                    gaussians.rotations.sizes() == at::IntArrayRef({n, 4}),
              "seen_from: covariances (N, 6), or scales (N, 3) with rotations (N, 4), must be given for the ", n,
              " means; got covariances ", describe(given), ", scales ", describe(gaussians.scales), ", rotations ",
              describe(gaussians.rotations));
  const at::TensorOptions options = gaussians.means.options();
  const at::Tensor placement = camera.world_to_camera.to(options);
  const at::Tensor k = camera.intrinsics.to(options), k0 = k.detach();
  // A: the intrinsics' values to the tensors', identity in value.
  const at::Tensor zero = at::zeros({}, options), one = at::ones({}, options);
  const at::Tensor a = at::stack({k[0] / k0[0], zero, (k[2] - k0[2]) / k0[0],  //
                                  zero, k[1] / k0[1], (k[3] - k0[3]) / k0[1],  //
                                  zero, zero, one})
                           .view({3, 3});
  const at::Tensor map = a.matmul(placement.slice(0, 0, 3).slice(1, 0, 3));
  const at::Tensor shift = a.matmul(placement.slice(0, 0, 3).select(1, 3));
  at::Tensor covariances = gaussians.covariances;
  if (!covariances.defined()) {
    const at::Tensor r = rotation_matrices(gaussians.rotations);
    covariances = packed((r * gaussians.scales.square().unsqueeze(1)).matmul(r.transpose(1, 2)));
  }
  Gaussians moved;
  moved.means = at::addmm(shift.unsqueeze(0), gaussians.means, map.t());
  moved.covariances = packed(map.matmul(unpacked(covariances)).matmul(map.t()));
  moved.opacities = gaussians.opacities;
  moved.features = gaussians.features;
  return moved;
}

}  // namespace sfgs
