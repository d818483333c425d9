#pragma once
// Gaussians moved into a camera's frame on the device. A recorded CUDA graph bakes the splatting op's camera into its
// launches; reading the camera's placement (world_to_camera = [R | t]) from device memory instead lets one recording
// serve a moving camera: the training step's frames and the Animator's. The Gaussians moved by these values are
// rendered by the same camera at the origin (camera_at_origin_of) and give the image the camera gives the world.
#include <cstdint>

#include <ATen/core/Tensor.h>

#include "ops/splat/splat.h"

namespace sfgs {

inline constexpr int64_t kCameraFrameRotationValues = 9;
inline constexpr int64_t kCameraFrameTranslationValues = 3;
inline constexpr int64_t kCameraFrameCovarianceValues = 36;
inline constexpr int64_t kCameraFrameValues =
    kCameraFrameRotationValues + kCameraFrameTranslationValues + kCameraFrameCovarianceValues;

// Writes the camera's placement to out[0, kCameraFrameValues): R row-major (9), t (3), and the (6, 6) map of a packed
// covariance's six values (xx, xy, xz, yy, yz, zz) to those of R Sigma R^T, made on the host so the device applies one
// product.
void write_camera_frame(const Camera& camera, float* out);

// Views of a (kCameraFrameValues) tensor that holds write_camera_frame's values (on any device, refilled per frame).
struct CameraFrame {
  at::Tensor rotation;        // (3, 3)
  at::Tensor translation;     // (3)
  at::Tensor covariance_map;  // (6, 6)

  CameraFrame() = default;
  explicit CameraFrame(const at::Tensor& values);
  bool defined() const { return rotation.defined(); }
  // World points (N, 3), directions (N, 3) and packed covariances (N, 6) in the camera's frame; differentiable, no
  // host synchronisation.
  at::Tensor points(const at::Tensor& points) const;
  at::Tensor directions(const at::Tensor& directions) const;
  at::Tensor covariances(const at::Tensor& covariances) const;
};

// World points (N, 3) in `camera`'s frame and directions (N, 3) rotated into it, from the camera on the host (a camera
// at the origin: returned as given, nothing uploaded). Differentiable; for eager work (a recorded graph reads its
// placement through a CameraFrame).
at::Tensor points_in_camera_frame(const at::Tensor& points, const Camera& camera);
at::Tensor directions_in_camera_frame(const at::Tensor& directions, const Camera& camera);

// Where points (N, 3) in a camera's frame fall in its image: the depth clamped to the near plane (safe to divide by),
// the pixel coordinates, and whether each point is in view (beyond the near plane and inside the image; a non-finite
// point is not). No host synchronisation.
struct PixelView {
  at::Tensor depth, u, v;  // (N)
  at::Tensor inside;       // (N) bool
};
PixelView pixel_view(const at::Tensor& camera_points, const Camera& camera);

// The camera with its intrinsics and image size at the origin (world_to_camera the identity).
Camera camera_at_origin_of(Camera camera);

// The same view with the principal point at the image's centre: world_to_camera's first two rows take a multiple of
// the depth row (a shear that keeps every depth), so each point and each covariance projects where `camera` projects
// it. A recording that bakes the intrinsics then serves every crop of an image size (the crop's placement read from
// the device, as above). world_to_camera is no longer a rotation: for points and covariances, not view directions.
Camera with_centred_principal_point(Camera camera);

// A camera whose placement and intrinsics may carry a gradient. The op takes its camera as numbers; a caller that
// wants the image's gradient with respect to the camera moves the Gaussians instead (seen_from) and renders them with
// the camera's value at the origin.
struct CameraTensors {
  at::Tensor world_to_camera;  // (4, 4), its last row (0, 0, 0, 1)
  at::Tensor intrinsics;       // (4): fx, fy, cx, cy in pixels
  int64_t width = 0, height = 0;
  double near_plane = kDefaultNearPlane;
  double far_plane = kDefaultFarPlane;

  bool requires_grad() const { return world_to_camera.requires_grad() || intrinsics.requires_grad(); }
  // Its value (a host read of 20 numbers), checked by the op when rendered.
  Camera value() const;
};

// Gaussians moved so that camera_at_origin_of(camera.value()) renders the image `camera` gives them, differentiable
// with respect to the Gaussians and both of the camera's tensors: points x -> A (R x + t) and covariances S ->
// (A R) S (A R)^T, where A = [[fx / fx0, 0, (cx - cx0) / fx0], [0, fy / fy0, (cy - cy0) / fy0], [0, 0, 1]] takes the
// intrinsics' values (fx0, ...) to the tensors' (the identity in value: a camera-space x scaled by fx / fx0 projects
// as fx would, and a shear by the depth moves the principal point). Scales and rotations are turned into
// covariances first; the result has means, covariances, opacities and features.
Gaussians seen_from(const Gaussians& gaussians, const CameraTensors& camera);

}  // namespace sfgs
