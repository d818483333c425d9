#pragma once
// Small 3D geometry for building the procedural body (csrc/body/procedural_body.h): a double-precision vector, its
// mirror image across the body's symmetry plane x = 0, and heights measured from the floor.
#include <array>
#include <cmath>

namespace sfgs::body::procedural {

using Vec3 = std::array<double, 3>;

inline Vec3 operator+(const Vec3& a, const Vec3& b) { return {a[0] + b[0], a[1] + b[1], a[2] + b[2]}; }
inline Vec3 operator-(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
inline Vec3 operator*(double s, const Vec3& a) { return {s * a[0], s * a[1], s * a[2]}; }
inline double dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
inline Vec3 normalized(const Vec3& a) { return (1.0 / std::sqrt(dot(a, a))) * a; }
inline Vec3 mirrored(const Vec3& a) { return {-a[0], a[1], a[2]}; }
inline double radians(double degrees) { return degrees * M_PI / 180.0; }

// Heights of the body's design are above the floor, which sits at this y so that the pelvis is near y = 0 as in
// SMPL-X.
inline constexpr double kFloorY = -0.93;
inline Vec3 at_height(double x, double h, double z) { return {x, h + kFloorY, z}; }

}  // namespace sfgs::body::procedural
