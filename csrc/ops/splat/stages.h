#pragma once
// The per-Gaussian and per-tile steps that both backends take, written once on top of pair_math.h: reading a
// Gaussian from the input arrays, culling and projecting it onto its tile rectangle, the exact test of that
// rectangle's tiles, and turning a Gaussian's summed projected gradient into its input gradients. The CPU reference
// calls these from its loops, the CUDA kernels from their threads. No torch in here.
#include <cstdint>

#include "ops/splat/pair_math.h"
#include "ops/splat/constants.h"

namespace sfgs::splat {

// The op's inputs as contiguous arrays of one floating type, with the camera and projection settings in that type.
template <typename T> struct SplatScene {
  PinholeCamera<T> camera;
  ProjectionSettings projection;
  const T* means;        // (N, 3)
  const T* scales;       // (N, 3), null when covariances are given
  const T* rotations;    // (N, 4), null when covariances are given
  const T* covariances;  // (N, 6), null when scales and rotations are given
  const T* opacities;    // (N)
  const T* features;     // (N, C)
  const T* background;   // (C)
  int64_t count;         // N
  int channels;          // C
};

// Gradient arrays shaped like the inputs; the unused parameterisation is null, as in the scene.
template <typename T> struct Gradients {
  T* means;
  T* scales;
  T* rotations;
  T* covariances;
  T* opacities;
  T* features;
  T* background;
};

// The image's kTileSize x kTileSize tiles, row-major.
struct TileGrid {
  int width, height, tiles_x, tiles_y;
};

SFGS_HD TileGrid make_grid(int width, int height) {
  return TileGrid{width, height, (width + kTileSize - 1) / kTileSize, (height + kTileSize - 1) / kTileSize};
}

SFGS_HD int64_t tile_count(const TileGrid& grid) { return int64_t(grid.tiles_x) * grid.tiles_y; }

// Gradient w.r.t. one projected Gaussian (the ProjectedField values blending reads), summed over the pixels it was
// blended into; a backend's per-intersection gradient slot holds these, followed by the C feature gradients.
enum ProjectedGradField : int {
  kGradMeanX,
  kGradMeanY,
  kGradConicA,
  kGradConicB,
  kGradConicC,
  kGradOpacity,
  kGradDepth,
  kProjectedGradWidth
};

// ---- reading a Gaussian -----------------------------------------------------------------------------------------

template <typename T> SFGS_HD Vec3<T> load_mean(const SplatScene<T>& s, int64_t i) {
  return Vec3<T>(s.means[3 * i], s.means[3 * i + 1], s.means[3 * i + 2]);
}

// World-space covariance of Gaussian i from whichever parameterisation the scene has; usable is false when it cannot
// be rendered (see covariance_from_scale_rotation and covariance_usable).
template <typename T> SFGS_HD Mat3<T> world_covariance(const SplatScene<T>& s, int64_t i, bool& usable) {
  Mat3<T> cov(T(0));
  if (s.covariances != nullptr) {
    cov = unpack_covariance(s.covariances + 6 * i);
    usable = covariance_usable(cov);
  } else {
    const T* sc = s.scales + 3 * i;
    const T* q = s.rotations + 4 * i;
    usable = covariance_from_scale_rotation(Vec3<T>(sc[0], sc[1], sc[2]), Vec4<T>(q[0], q[1], q[2], q[3]), cov);
  }
  return cov;
}

template <typename T> SFGS_HD bool features_finite(const SplatScene<T>& s, int64_t i) {
  const T* f = s.features + i * s.channels;
  for (int c = 0; c < s.channels; ++c)
    if (!is_finite(f[c])) return false;
  return true;
}

// ---- projection and tiles ------------------------------------------------------------------------------------------

// Culls and projects Gaussian i. True when it lands on the image: then g, its tile rectangle (inclusive, clipped to
// the image) and its screen radius are set. Whether it touches any tile of that rectangle is for the tile test.
template <typename T>
SFGS_HD bool project_to_tiles(const SplatScene<T>& s, int64_t i, ProjectedGaussian<T>& g, PixelRect& tiles,
                              Vec2<T>& radius) {
  bool usable = false;
  const Mat3<T> cov = world_covariance(s, i, usable);
  PixelRect pixels;
  if (!usable || !features_finite(s, i) ||
      !project_gaussian(s.camera, s.projection, load_mean(s, i), cov, s.opacities[i], g, pixels, radius))
    return false;
  tiles = tile_rect(pixels);
  return true;
}

// Tiles of a rectangle: the bound on a Gaussian's intersections before the exact test.
SFGS_HD int64_t rect_area(const PixelRect& r) { return int64_t(r.x1 - r.x0 + 1) * (r.y1 - r.y0 + 1); }

// Calls on_tile(tx, ty) for every tile of the rectangle that g touches (tile_touches, row-major) and returns how
// many it touches; 0 culls the Gaussian.
template <typename T, typename OnTile>
SFGS_HD int64_t count_touched_tiles(const ProjectedGaussian<T>& g, const PixelRect& tiles, const TileGrid& grid,
                                    OnTile&& on_tile) {
  int64_t touched = 0;
  for (int ty = tiles.y0; ty <= tiles.y1; ++ty)
    for (int tx = tiles.x0; tx <= tiles.x1; ++tx)
      if (tile_touches(g, tx, ty, grid.width, grid.height)) {
        ++touched;
        on_tile(tx, ty);
      }
  return touched;
}

// ---- backward ------------------------------------------------------------------------------------------------------

// Writes the input gradients of Gaussian i (means, opacities and covariances, or scales and rotations; not features)
// from grad, its projected gradient (kProjectedGradWidth values in ProjectedGradField order). Only for Gaussians that
// project_to_tiles accepted.
template <typename T>
SFGS_HD void write_input_gradients(const SplatScene<T>& s, int64_t i, const T* grad, const Gradients<T>& out) {
  bool usable = false;
  const Mat3<T> cov = world_covariance(s, i, usable);
  Vec3<T> grad_mean(T(0));
  Mat3<T> grad_cov(T(0));
  T grad_opacity = T(0);
  project_gaussian_vjp(s.camera, s.projection, load_mean(s, i), cov, s.opacities[i],
                       Vec2<T>(grad[kGradMeanX], grad[kGradMeanY]),
                       Vec3<T>(grad[kGradConicA], grad[kGradConicB], grad[kGradConicC]), grad[kGradOpacity],
                       grad[kGradDepth], grad_mean, grad_cov, grad_opacity);
  for (int k = 0; k < 3; ++k) out.means[3 * i + k] = grad_mean[k];
  out.opacities[i] = grad_opacity;
  if (s.covariances != nullptr) {
    pack_covariance_gradient(grad_cov, out.covariances + 6 * i);
    return;
  }
  const T* sc = s.scales + 3 * i;
  const T* q = s.rotations + 4 * i;
  Vec3<T> grad_scale(T(0));
  Vec4<T> grad_quaternion(T(0));
  covariance_from_scale_rotation_vjp(Vec3<T>(sc[0], sc[1], sc[2]), Vec4<T>(q[0], q[1], q[2], q[3]), grad_cov,
                                     grad_scale, grad_quaternion);
  for (int k = 0; k < 3; ++k) out.scales[3 * i + k] = grad_scale[k];
  for (int k = 0; k < 4; ++k) out.rotations[4 * i + k] = grad_quaternion[k];
}

// Zero input gradients (features excepted) for a Gaussian that was culled.
template <typename T> SFGS_HD void write_zero_gradients(const SplatScene<T>& s, int64_t i, const Gradients<T>& out) {
  for (int k = 0; k < 3; ++k) out.means[3 * i + k] = T(0);
  out.opacities[i] = T(0);
  if (s.covariances != nullptr) {
    for (int k = 0; k < 6; ++k) out.covariances[6 * i + k] = T(0);
    return;
  }
  for (int k = 0; k < 3; ++k) out.scales[3 * i + k] = T(0);
  for (int k = 0; k < 4; ++k) out.rotations[4 * i + k] = T(0);
}

}  // namespace sfgs::splat
