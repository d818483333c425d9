#pragma once
// sfgs's differentiable 3D Gaussian splatting op: one autograd node, a CPU reference backend and a CUDA backend
// chosen by the tensors' device. See docs/splatting.md for conventions and for which inputs are errors and which
// are culled.
#include <array>
#include <string>

#include <ATen/core/Tensor.h>

#include "ops/splat/constants.h"

namespace sfgs {

// Pinhole camera, OpenCV convention (x right, y down, z forward), pixel centres at integer + 0.5.
struct Camera {
  std::array<double, 16> world_to_camera;  // row-major 4x4; the last row must be (0, 0, 0, 1)
  double fx, fy, cx, cy;                   // pixels; the principal point is honoured
  int64_t width, height;
  double near_plane = kDefaultNearPlane;
  double far_plane = kDefaultFarPlane;

  // From a (4, 4) tensor of any floating dtype and device (a device tensor is copied to the host once).
  static Camera from_tensor(const at::Tensor& world_to_camera, double fx, double fy, double cx, double cy,
                            int64_t width, int64_t height, double near_plane = kDefaultNearPlane,
                            double far_plane = kDefaultFarPlane);
  // Camera at the origin looking along +z with the principal point at the image centre.
  static Camera looking_forward(double focal, int64_t width, int64_t height);
};

// Empty when the camera can be rendered with; otherwise what is wrong with it, naming the field and the value (a
// non-finite entry, a rotation block that is not orthonormal with det +1, a non-positive focal length, ...).
// render() refuses such a camera with this text; dataset readers use it to name the frame.
std::string camera_problem(const Camera& camera);
// The part of it about the placement alone: world_to_camera finite, its last row (0, 0, 0, 1), its rotation block a
// proper rotation (within kCameraRotationTolerance). For readers of camera files that hold no intrinsics.
std::string world_to_camera_problem(const std::array<double, 16>& world_to_camera);

// The camera's centre in world coordinates: -R^T t of world_to_camera = [R | t].
std::array<double, 3> camera_centre(const Camera& camera);
// Whether world_to_camera is exactly the identity: the world is the camera's frame.
bool camera_at_origin(const Camera& camera);

// One parameterisation of the 3D covariance must be given: scales (N,3) with rotations (N,4; quaternions
// w,x,y,z, normalised inside), or covariances (N,6: xx, xy, xz, yy, yz, zz).
struct Gaussians {
  at::Tensor means;        // (N, 3) world positions
  at::Tensor scales;       // (N, 3) standard deviations along the rotated axes
  at::Tensor rotations;    // (N, 4)
  at::Tensor covariances;  // (N, 6)
  at::Tensor opacities;    // (N) or (N, 1), in [0, 1]
  at::Tensor features;     // (N, C), C >= 1: colours or any per-Gaussian feature
};

// A CUDA render reads one count back from the device to size its intersection buffers: its one host
// synchronisation, which a CUDA graph cannot capture. Given a BinningBudget (RenderOptions::budget), CUDA renders size
// those buffers from the budget instead and copy the pass's true counts into `counts` (a CUDA int64 tensor of
// BinningBudget::kCounts: intersections, longest tile, invalid opacities); a pass beyond the budget, or with invalid
// opacities, renders only the background. The caller checks the counts once the work is done and renders again with
// a larger budget (ops/splat/growing_budget.h; model::Animator does). CPU renders ignore it.
struct BinningBudget {
  static constexpr int64_t kCounts = 3;
  int64_t intersections = 0;
  int64_t longest_tile = 0;  // Gaussians in the busiest tile
  at::Tensor counts;
};

struct RenderOptions {
  bool low_pass = true;                   // add kLowPassVariancePx2 to every 2D covariance
  bool antialiased = false;               // opacity compensation as in mip-splatting (implies the low-pass)
  bool check_background = false;          // also check a CUDA background is finite (a device-to-host read; CPU: always)
  bool deterministic = false;             // CUDA: bit-identical gradients across runs (the CPU backend always is)
  const BinningBudget* budget = nullptr;  // CUDA: buffers sized from this budget, no host read (recorded work)
};

struct RenderResult {
  at::Tensor image;    // (H, W, C): blended features plus transmittance * background
  at::Tensor alpha;    // (H, W): 1 - final transmittance
  at::Tensor depth;    // (H, W): expected camera-space depth of the blended Gaussians; 0 where alpha is 0
  at::Tensor radii;    // (N, 2) int32: screen half extents (pixels) of the alpha >= 1/255 ellipse; 0 when culled
  at::Tensor visible;  // (N) bool: the Gaussian touches at least one tile of the image
};

// Differentiable w.r.t. means, scales, rotations, covariances, opacities, features and background.
RenderResult render(const Gaussians& gaussians, const at::Tensor& background, const Camera& camera,
                    const RenderOptions& options = {});

// Whether this build has the CUDA backend.
bool cuda_backend_available();

}  // namespace sfgs
