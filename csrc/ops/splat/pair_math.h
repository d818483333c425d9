#pragma once
// The splatting math, written once for the CPU reference (float and double) and the CUDA kernels: per-Gaussian
// EWA projection and its vector-Jacobian product, the exact ellipse/tile test, and the per-pixel-pair alpha with
// its gradient. Both backends call exactly these functions, so they cannot drift apart. No torch in here.
#include <cmath>
#include <cstdint>

#include <glm/glm.hpp>

#include "common/constants.h"
#include "common/host_device.h"
#include "ops/splat/constants.h"

namespace sfgs::splat {

template <typename T> using Vec2 = glm::vec<2, T, glm::defaultp>;
template <typename T> using Vec3 = glm::vec<3, T, glm::defaultp>;
template <typename T> using Vec4 = glm::vec<4, T, glm::defaultp>;
// glm matrices are column-major: m[column][row].
template <typename T> using Mat2 = glm::mat<2, 2, T, glm::defaultp>;
template <typename T> using Mat3 = glm::mat<3, 3, T, glm::defaultp>;
template <typename T> using Mat2x3 = glm::mat<3, 2, T, glm::defaultp>;  // 2 rows, 3 columns

// Pinhole camera in OpenCV convention (x right, y down, z forward); world_to_camera rotation and translation.
template <typename T> struct PinholeCamera {
  Mat3<T> rotation;
  Vec3<T> translation;
  T fx, fy, cx, cy;
  int width, height;
  T near_plane, far_plane;
};

struct ProjectionSettings {
  double low_pass_variance;  // px^2 added to the 2D covariance (0 disables the low-pass)
  bool antialiased;          // scale opacity by sqrt(det(S) / det(S + low-pass)), as mip-splatting
};

// What blending needs of one projected Gaussian.
template <typename T> struct ProjectedGaussian {
  Vec2<T> mean;   // pixel coordinates
  Vec3<T> conic;  // inverse 2D covariance (a, b, c) = [[a, b], [b, c]]
  T opacity;      // after antialiasing compensation
  T depth;        // camera-space z
  T level;        // sigma = 0.5 d^T conic d above which alpha < kMinAlpha: ln(opacity / kMinAlpha)
};

// How both backends store a projected Gaussian between projection and blending: kProjectedWidth values per row.
enum ProjectedField : int { kMeanX, kMeanY, kConicA, kConicB, kConicC, kOpacity, kDepth, kLevel, kProjectedWidth };

template <typename T> SFGS_HD ProjectedGaussian<T> load_projected(const T* p) {
  ProjectedGaussian<T> g;
  g.mean = Vec2<T>(p[kMeanX], p[kMeanY]);
  g.conic = Vec3<T>(p[kConicA], p[kConicB], p[kConicC]);
  g.opacity = p[kOpacity];
  g.depth = p[kDepth];
  g.level = p[kLevel];
  return g;
}

template <typename T> SFGS_HD void store_projected(const ProjectedGaussian<T>& g, T* p) {
  p[kMeanX] = g.mean[0];
  p[kMeanY] = g.mean[1];
  p[kConicA] = g.conic[0];
  p[kConicB] = g.conic[1];
  p[kConicC] = g.conic[2];
  p[kOpacity] = g.opacity;
  p[kDepth] = g.depth;
  p[kLevel] = g.level;
}

// Inclusive pixel and tile rectangles touched by a projected Gaussian (empty when x0 > x1).
struct PixelRect {
  int x0, y0, x1, y1;
};

template <typename T> SFGS_HD T clamp_value(T v, T lo, T hi) { return v < lo ? lo : (v > hi ? hi : v); }
template <typename T> SFGS_HD bool is_finite(T v) { return v - v == v - v; }  // false for NaN and +-Inf

// Elementary functions resolved per precision, identically on host and device (never float silently promoted).
SFGS_HD float sqrt_of(float v) { return sqrtf(v); }
SFGS_HD double sqrt_of(double v) { return ::sqrt(v); }
SFGS_HD float log_of(float v) { return logf(v); }
SFGS_HD double log_of(double v) { return ::log(v); }
SFGS_HD float ceil_of(float v) { return ceilf(v); }
SFGS_HD double ceil_of(double v) { return ::ceil(v); }
SFGS_HD float floor_of(float v) { return floorf(v); }
SFGS_HD double floor_of(double v) { return ::floor(v); }
SFGS_HD double exp_of(double v) { return ::exp(v); }
SFGS_HD float exp_of(float v) {
#if defined(__CUDA_ARCH__)
  return __expf(v);
#else
  return expf(v);
#endif
}

// ---- 3D covariance ------------------------------------------------------------------------------------------

// Packed symmetric 3x3 layout shared by inputs and gradients: (xx, xy, xz, yy, yz, zz).
template <typename T> SFGS_HD Mat3<T> unpack_covariance(const T* c) {
  Mat3<T> m;
  m[0][0] = c[0];
  m[1][0] = c[1];
  m[2][0] = c[2];
  m[0][1] = c[1];
  m[1][1] = c[3];
  m[2][1] = c[4];
  m[0][2] = c[2];
  m[1][2] = c[4];
  m[2][2] = c[5];
  return m;
}

// Gradient w.r.t. the six packed entries from the gradient w.r.t. the full matrix (off-diagonals appear twice).
template <typename T> SFGS_HD void pack_covariance_gradient(const Mat3<T>& g, T* out) {
  out[0] = g[0][0];
  out[1] = g[1][0] + g[0][1];
  out[2] = g[2][0] + g[0][2];
  out[3] = g[1][1];
  out[4] = g[2][1] + g[1][2];
  out[5] = g[2][2];
}

// A 3D covariance is usable when its diagonal is finite and non-negative; definiteness of the projection
// is checked in project_gaussian.
template <typename T> SFGS_HD bool covariance_usable(const Mat3<T>& m) {
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      if (!is_finite(m[i][j])) return false;
  return m[0][0] >= T(0) && m[1][1] >= T(0) && m[2][2] >= T(0);
}

// Rotation from a unit quaternion (w, x, y, z).
template <typename T> SFGS_HD Mat3<T> rotation_from_unit_quaternion(const Vec4<T>& q) {
  const T w = q[0], x = q[1], y = q[2], z = q[3];
  Mat3<T> r;
  r[0][0] = T(1) - T(2) * (y * y + z * z);
  r[1][0] = T(2) * (x * y - w * z);
  r[2][0] = T(2) * (x * z + w * y);
  r[0][1] = T(2) * (x * y + w * z);
  r[1][1] = T(1) - T(2) * (x * x + z * z);
  r[2][1] = T(2) * (y * z - w * x);
  r[0][2] = T(2) * (x * z - w * y);
  r[1][2] = T(2) * (y * z + w * x);
  r[2][2] = T(1) - T(2) * (x * x + y * y);
  return r;
}

// Sigma = R S S^T R^T with R from the (normalised inside) quaternion. Returns false when the quaternion cannot be
// normalised or any input is not finite.
template <typename T>
SFGS_HD bool covariance_from_scale_rotation(const Vec3<T>& scale, const Vec4<T>& quaternion, Mat3<T>& covariance) {
  const T norm = sqrt_of(glm::dot(quaternion, quaternion));
  if (!is_finite(norm) || !(norm > T(kMinQuaternionNorm))) return false;
  if (!is_finite(scale[0]) || !is_finite(scale[1]) || !is_finite(scale[2])) return false;
  const Mat3<T> r = rotation_from_unit_quaternion(quaternion / norm);
  Mat3<T> m;
  for (int col = 0; col < 3; ++col) m[col] = r[col] * scale[col];
  covariance = m * glm::transpose(m);
  return covariance_usable(covariance);
}

// Vector-Jacobian product of covariance_from_scale_rotation for a symmetric full-matrix gradient.
template <typename T>
SFGS_HD void covariance_from_scale_rotation_vjp(const Vec3<T>& scale, const Vec4<T>& quaternion,
                                                const Mat3<T>& grad_covariance, Vec3<T>& grad_scale,
                                                Vec4<T>& grad_quaternion) {
  const T norm = sqrt_of(glm::dot(quaternion, quaternion));
  const Vec4<T> q = quaternion / norm;
  const Mat3<T> r = rotation_from_unit_quaternion(q);
  Mat3<T> m;
  for (int col = 0; col < 3; ++col) m[col] = r[col] * scale[col];
  const Mat3<T> grad_m = T(2) * grad_covariance * m;  // Sigma = M M^T, gradient symmetric
  Mat3<T> g;                                          // gradient w.r.t. the rotation matrix
  for (int col = 0; col < 3; ++col) {
    grad_scale[col] = glm::dot(grad_m[col], r[col]);
    g[col] = grad_m[col] * scale[col];
  }
  const T w = q[0], x = q[1], y = q[2], z = q[3];
  // g[col][row] is dL/dR(row, col).
  const T g00 = g[0][0], g01 = g[1][0], g02 = g[2][0];
  const T g10 = g[0][1], g11 = g[1][1], g12 = g[2][1];
  const T g20 = g[0][2], g21 = g[1][2], g22 = g[2][2];
  Vec4<T> grad_unit;
  grad_unit[0] = T(2) * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21);
  grad_unit[1] = T(2) * (y * g01 + z * g02 + y * g10 - T(2) * x * g11 - w * g12 + z * g20 + w * g21 - T(2) * x * g22);
  grad_unit[2] = T(2) * (-T(2) * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21 - T(2) * y * g22);
  grad_unit[3] = T(2) * (-T(2) * z * g00 - w * g01 + x * g02 + w * g10 - T(2) * z * g11 + y * g12 + x * g20 + y * g21);
  // Normalisation: only the component orthogonal to q survives.
  grad_quaternion = (grad_unit - q * glm::dot(q, grad_unit)) / norm;
}

// ---- projection ---------------------------------------------------------------------------------------------

// Intermediates shared by the forward projection and its vector-Jacobian product.
template <typename T> struct ProjectionTerms {
  Vec3<T> camera_point;  // mean in camera space
  Mat3<T> camera_cov;    // covariance in camera space
  Vec2<T> tangent;       // x/z, y/z clamped to the FOV guard (used in J)
  bool clamped_x, clamped_y;
  Mat2x3<T> jacobian;
  T a0, b, c0;           // projected 2D covariance before the low-pass
  T a, c;                // diagonal after the low-pass
  T det_original, det;   // determinants before and after the low-pass
  T compensation_ratio;  // det_original / det (before the floor), only meaningful when antialiased
  T compensation;
};

template <typename T>
SFGS_HD bool projection_terms(const PinholeCamera<T>& cam, const ProjectionSettings& settings, const Vec3<T>& mean,
                              const Mat3<T>& covariance, ProjectionTerms<T>& t) {
  t.camera_point = cam.rotation * mean + cam.translation;
  const T z = t.camera_point[2];
  if (!(z >= cam.near_plane && z <= cam.far_plane)) return false;  // also rejects NaN
  if (!is_finite(t.camera_point[0]) || !is_finite(t.camera_point[1])) return false;
  t.camera_cov = cam.rotation * covariance * glm::transpose(cam.rotation);

  const T guard_x = T(kFovGuardFraction) * T(0.5) * T(cam.width) / cam.fx;
  const T guard_y = T(kFovGuardFraction) * T(0.5) * T(cam.height) / cam.fy;
  const T raw_x = t.camera_point[0] / z, raw_y = t.camera_point[1] / z;
  t.tangent[0] = clamp_value(raw_x, -cam.cx / cam.fx - guard_x, (T(cam.width) - cam.cx) / cam.fx + guard_x);
  t.tangent[1] = clamp_value(raw_y, -cam.cy / cam.fy - guard_y, (T(cam.height) - cam.cy) / cam.fy + guard_y);
  t.clamped_x = t.tangent[0] != raw_x;
  t.clamped_y = t.tangent[1] != raw_y;

  // J = [[fx/z, 0, -fx tx/z], [0, fy/z, -fy ty/z]]; written via tx/z, never x/z^2, so huge depths cannot overflow.
  Mat2x3<T> j(T(0));
  j[0][0] = cam.fx / z;
  j[2][0] = -cam.fx * t.tangent[0] / z;
  j[1][1] = cam.fy / z;
  j[2][1] = -cam.fy * t.tangent[1] / z;
  t.jacobian = j;
  const Mat2<T> s = j * t.camera_cov * glm::transpose(j);
  t.a0 = s[0][0];
  t.b = T(0.5) * (s[1][0] + s[0][1]);
  t.c0 = s[1][1];
  t.det_original = t.a0 * t.c0 - t.b * t.b;
  if (!(t.a0 >= T(0) && t.c0 >= T(0) && t.det_original >= -T(kPsdTolerance) * t.a0 * t.c0)) return false;

  const T blur = T(settings.low_pass_variance);
  t.a = t.a0 + blur;
  t.c = t.c0 + blur;
  t.det = t.a * t.c - t.b * t.b;
  if (!is_finite(t.det) || !(t.det > T(kMinDeterminant2D))) return false;

  t.compensation_ratio = T(0);
  t.compensation = T(1);
  if (settings.antialiased) {
    t.compensation_ratio = (t.det_original > T(0) ? t.det_original : T(0)) / t.det;
    const T floor2 = T(kMinCompensation * kMinCompensation);
    t.compensation = sqrt_of(t.compensation_ratio > floor2 ? t.compensation_ratio : floor2);
  }
  return true;
}

// Screen-space rectangle of pixels whose centres lie inside the ellipse sigma <= level, clipped to the image.
template <typename T>
SFGS_HD PixelRect pixel_rect(const ProjectedGaussian<T>& g, T var_x, T var_y, int width, int height) {
  const T extent_x = sqrt_of(T(2) * g.level * var_x), extent_y = sqrt_of(T(2) * g.level * var_y);
  // Clamp in floating point before converting, so huge footprints cannot overflow an int.
  const T lo_x = clamp_value(g.mean[0] - extent_x - T(kPixelCentre), T(-1), T(width));
  const T hi_x = clamp_value(g.mean[0] + extent_x - T(kPixelCentre), T(-1), T(width));
  const T lo_y = clamp_value(g.mean[1] - extent_y - T(kPixelCentre), T(-1), T(height));
  const T hi_y = clamp_value(g.mean[1] + extent_y - T(kPixelCentre), T(-1), T(height));
  PixelRect r;
  r.x0 = static_cast<int>(ceil_of(lo_x));
  r.x1 = static_cast<int>(floor_of(hi_x));
  r.y0 = static_cast<int>(ceil_of(lo_y));
  r.y1 = static_cast<int>(floor_of(hi_y));
  r.x0 = r.x0 < 0 ? 0 : r.x0;
  r.y0 = r.y0 < 0 ? 0 : r.y0;
  r.x1 = r.x1 > width - 1 ? width - 1 : r.x1;
  r.y1 = r.y1 > height - 1 ? height - 1 : r.y1;
  return r;
}

// Half extent (pixels, rounded up) reported for a Gaussian the projection accepted: at least 1, so "radius > 0"
// means visible, and clamped so huge footprints cannot overflow an int.
template <typename T> SFGS_HD int32_t pixel_radius(T radius) {
  const T up = ceil_of(radius);
  return up >= T(2147483647) ? 2147483647 : (up < T(1) ? 1 : int32_t(up));
}

SFGS_HD bool rect_empty(const PixelRect& r) { return r.x0 > r.x1 || r.y0 > r.y1; }

SFGS_HD PixelRect tile_rect(const PixelRect& pixels) {
  return PixelRect{pixels.x0 / kTileSize, pixels.y0 / kTileSize, pixels.x1 / kTileSize, pixels.y1 / kTileSize};
}

// Full projection of one Gaussian. Returns false (culled) when it is behind the near plane, beyond the far
// plane, not finite, degenerate, too transparent to reach kMinAlpha anywhere, or entirely off-screen.
template <typename T>
SFGS_HD bool project_gaussian(const PinholeCamera<T>& cam, const ProjectionSettings& settings, const Vec3<T>& mean,
                              const Mat3<T>& covariance, T opacity, ProjectedGaussian<T>& out, PixelRect& pixels,
                              Vec2<T>& radius) {
  if (!is_finite(opacity) || !covariance_usable(covariance)) return false;
  ProjectionTerms<T> t;
  if (!projection_terms(cam, settings, mean, covariance, t)) return false;
  out.opacity = opacity * t.compensation;
  if (!(out.opacity >= T(kMinAlpha))) return false;
  out.level = log_of(out.opacity / T(kMinAlpha));
  const T inv_det = T(1) / t.det;
  out.conic = Vec3<T>(t.c * inv_det, -t.b * inv_det, t.a * inv_det);
  if (!is_finite(out.conic[0]) || !is_finite(out.conic[1]) || !is_finite(out.conic[2])) return false;
  const T z = t.camera_point[2];
  out.mean = Vec2<T>(cam.fx * (t.camera_point[0] / z) + cam.cx, cam.fy * (t.camera_point[1] / z) + cam.cy);
  out.depth = z;
  radius = Vec2<T>(sqrt_of(T(2) * out.level * t.a), sqrt_of(T(2) * out.level * t.c));
  pixels = pixel_rect(out, t.a, t.c, cam.width, cam.height);
  return !rect_empty(pixels);
}

// Gradient of the projection, given gradients w.r.t. the projected mean, conic, (compensated) opacity and depth.
// Recomputes the forward intermediates; call only for Gaussians project_gaussian accepted.
template <typename T>
SFGS_HD void project_gaussian_vjp(const PinholeCamera<T>& cam, const ProjectionSettings& settings, const Vec3<T>& mean,
                                  const Mat3<T>& covariance, T opacity, const Vec2<T>& grad_mean2d,
                                  const Vec3<T>& grad_conic, T grad_opacity_out, T grad_depth, Vec3<T>& grad_mean,
                                  Mat3<T>& grad_covariance, T& grad_opacity) {
  ProjectionTerms<T> t{};  // projection_terms fills every field for the accepted Gaussians this is called for
  projection_terms(cam, settings, mean, covariance, t);
  const T inv_det = T(1) / t.det;
  Mat2<T> conic;
  conic[0][0] = t.c * inv_det;
  conic[1][1] = t.a * inv_det;
  conic[0][1] = conic[1][0] = -t.b * inv_det;

  // conic = S^-1  =>  dL/dS = -S^-1 G S^-1, with G the symmetric full-matrix gradient of the conic.
  Mat2<T> g_conic;
  g_conic[0][0] = grad_conic[0];
  g_conic[1][1] = grad_conic[2];
  g_conic[0][1] = g_conic[1][0] = T(0.5) * grad_conic[1];
  Mat2<T> g_cov2d = -(conic * g_conic * conic);

  grad_opacity = grad_opacity_out * t.compensation;
  const T floor2 = T(kMinCompensation * kMinCompensation);
  if (settings.antialiased && t.compensation_ratio > floor2 && t.det_original > T(0)) {
    const T g_ratio = grad_opacity_out * opacity * T(0.5) / t.compensation;
    const T inv_det2 = inv_det * inv_det;
    const T d_a0 = (t.c0 * t.det - t.det_original * t.c) * inv_det2;
    const T d_c0 = (t.a0 * t.det - t.det_original * t.a) * inv_det2;
    const T d_b = -T(2) * t.b * (t.det - t.det_original) * inv_det2;
    g_cov2d[0][0] += g_ratio * d_a0;
    g_cov2d[1][1] += g_ratio * d_c0;
    g_cov2d[0][1] += T(0.5) * g_ratio * d_b;
    g_cov2d[1][0] += T(0.5) * g_ratio * d_b;
  }

  // S = J Sigma_c J^T (the low-pass is additive and passes the gradient unchanged).
  const Mat2x3<T>& j = t.jacobian;
  const Mat3<T> g_camera_cov = glm::transpose(j) * g_cov2d * j;
  const Mat2x3<T> g_j = T(2) * g_cov2d * j * t.camera_cov;
  grad_covariance = glm::transpose(cam.rotation) * g_camera_cov * cam.rotation;

  const T z = t.camera_point[2];
  const T inv_z = T(1) / z;
  const T tx = t.tangent[0], ty = t.tangent[1];
  // g_j[col][row]: entries (0,0)=fx/z, (0,2)=-fx tx/z, (1,1)=fy/z, (1,2)=-fy ty/z.
  T g_z = -cam.fx * inv_z * inv_z * g_j[0][0] - cam.fy * inv_z * inv_z * g_j[1][1] +
          cam.fx * tx * inv_z * inv_z * g_j[2][0] + cam.fy * ty * inv_z * inv_z * g_j[2][1];
  T g_x = T(0), g_y = T(0);
  if (!t.clamped_x) {
    const T g_tx = -cam.fx * inv_z * g_j[2][0];
    g_x += g_tx * inv_z;
    g_z -= g_tx * tx * inv_z;
  }
  if (!t.clamped_y) {
    const T g_ty = -cam.fy * inv_z * g_j[2][1];
    g_y += g_ty * inv_z;
    g_z -= g_ty * ty * inv_z;
  }
  // Projected mean (fx x/z + cx, fy y/z + cy), unclamped.
  const T raw_x = t.camera_point[0] * inv_z, raw_y = t.camera_point[1] * inv_z;
  g_x += grad_mean2d[0] * cam.fx * inv_z;
  g_y += grad_mean2d[1] * cam.fy * inv_z;
  g_z -= (grad_mean2d[0] * cam.fx * raw_x + grad_mean2d[1] * cam.fy * raw_y) * inv_z;
  g_z += grad_depth;
  grad_mean = glm::transpose(cam.rotation) * Vec3<T>(g_x, g_y, g_z);
}

// ---- tiles --------------------------------------------------------------------------------------------------

// Whether any pixel centre of the inclusive rectangle [px0, px1] x [py0, py1] (clipped to the image by the caller)
// can have sigma <= level: the minimum of the quadratic over the rectangle, exact on its edges. False guarantees
// that pair_alpha rejects every pixel of the rectangle; kTileTestSlack keeps rounding from dropping one it accepts.
// The CUDA blends also use it to skip Gaussians for a warp's block of pixels.
template <typename T>
SFGS_HD bool pixel_block_touched(const ProjectedGaussian<T>& g, int px0, int py0, int px1, int py1) {
  const T x0 = T(px0) + T(kPixelCentre) - g.mean[0], x1 = T(px1) + T(kPixelCentre) - g.mean[0];
  const T y0 = T(py0) + T(kPixelCentre) - g.mean[1], y1 = T(py1) + T(kPixelCentre) - g.mean[1];
  if (x0 <= T(0) && x1 >= T(0) && y0 <= T(0) && y1 >= T(0)) return true;
  const T a = g.conic[0], b = g.conic[1], c = g.conic[2];
  const T threshold = g.level * T(1 + kTileTestSlack) + T(kTileTestSlack);
  // Minimum of the quadratic on each edge: at fixed dx over dy in [y0, y1], and at fixed dy over dx in [x0, x1].
  T best = T(INFINITY);
  const T xs[2] = {x0, x1};
  const T ys[2] = {y0, y1};
  for (int k = 0; k < 2; ++k) {
    const T dx = xs[k];
    const T dy = clamp_value(-b * dx / c, y0, y1);
    const T s = T(0.5) * (a * dx * dx + c * dy * dy) + b * dx * dy;
    best = s < best ? s : best;
  }
  for (int k = 0; k < 2; ++k) {
    const T dy = ys[k];
    const T dx = clamp_value(-b * dy / a, x0, x1);
    const T s = T(0.5) * (a * dx * dx + c * dy * dy) + b * dx * dy;
    best = s < best ? s : best;
  }
  return best <= threshold;
}

// The tile test: pixel_block_touched on the tile's image-clipped pixel centres.
template <typename T>
SFGS_HD bool tile_touches(const ProjectedGaussian<T>& g, int tile_x, int tile_y, int width, int height) {
  const int px0 = tile_x * kTileSize, py0 = tile_y * kTileSize;
  const int px1 = (px0 + kTileSize < width ? px0 + kTileSize : width) - 1;
  const int py1 = (py0 + kTileSize < height ? py0 + kTileSize : height) - 1;
  return pixel_block_touched(g, px0, py0, px1, py1);
}

// ---- per pixel-Gaussian pair ----------------------------------------------------------------------------------

template <typename T> struct PairAlpha {
  T alpha;       // min(kMaxAlpha, opacity * vis)
  T vis;         // exp(-sigma)
  T dx, dy;      // pixel centre minus projected mean
  bool clamped;  // alpha hit kMaxAlpha: no geometric or opacity gradient (the true derivative is zero)
};

// Alpha of Gaussian g at the pixel centre (px, py); false when the pair is skipped (alpha < kMinAlpha).
template <typename T> SFGS_HD bool pair_alpha(const ProjectedGaussian<T>& g, T px, T py, PairAlpha<T>& p) {
  p.dx = px - g.mean[0];
  p.dy = py - g.mean[1];
  const T sigma = T(0.5) * (g.conic[0] * p.dx * p.dx + g.conic[2] * p.dy * p.dy) + g.conic[1] * p.dx * p.dy;
  if (sigma < T(0)) return false;  // only rounding of a near-singular conic can do this
  p.vis = exp_of(-sigma);
  const T raw = g.opacity * p.vis;
  p.clamped = raw > T(kMaxAlpha);
  p.alpha = p.clamped ? T(kMaxAlpha) : raw;
  return p.alpha >= T(kMinAlpha);
}

// Gradients of one pair's alpha w.r.t. the projected mean, conic and opacity, accumulated into the outputs.
template <typename T>
SFGS_HD void pair_alpha_vjp(const ProjectedGaussian<T>& g, const PairAlpha<T>& p, T grad_alpha, Vec2<T>& grad_mean,
                            Vec3<T>& grad_conic, T& grad_opacity) {
  if (p.clamped) return;
  grad_opacity += p.vis * grad_alpha;
  const T grad_sigma = -g.opacity * p.vis * grad_alpha;
  grad_conic[0] += T(0.5) * grad_sigma * p.dx * p.dx;
  grad_conic[1] += grad_sigma * p.dx * p.dy;
  grad_conic[2] += T(0.5) * grad_sigma * p.dy * p.dy;
  grad_mean[0] -= grad_sigma * (g.conic[0] * p.dx + g.conic[1] * p.dy);
  grad_mean[1] -= grad_sigma * (g.conic[1] * p.dx + g.conic[2] * p.dy);
}

// Expected depth of a pixel from its weighted depth sum and its alpha; 0 where nothing was blended. A blended pixel
// has alpha >= kMinAlpha, so the clamp only keeps the division finite.
template <typename T> SFGS_HD T expected_depth_of(T depth_sum, T alpha) {
  return alpha > T(0) ? depth_sum / (alpha > T(kMinAlpha) ? alpha : T(kMinAlpha)) : T(0);
}

// Gradient of the composite w.r.t. one pair's alpha, walking back to front. transmittance is T before this pair;
// behind_* hold what lies behind it (colour including the background term, depth, and the final transmittance).
// d/dalpha [x T + (1-alpha) * (behind / (1-alpha))] = x T - behind / (1 - alpha).
template <typename T>
SFGS_HD T composite_grad_alpha(T alpha, T transmittance, T colour_dot_grad, T behind_colour_dot_grad, T depth,
                               T grad_depth, T behind_depth, T final_transmittance, T grad_alpha_out) {
  const T inv_one_minus = T(1) / (T(1) - alpha);  // alpha <= kMaxAlpha, so this is at most 100
  return colour_dot_grad * transmittance - behind_colour_dot_grad * inv_one_minus +
         grad_depth * (depth * transmittance - behind_depth * inv_one_minus) +
         grad_alpha_out * final_transmittance * inv_one_minus;
}

}  // namespace sfgs::splat
