#pragma once
// The pixel losses' numbers, named once.

namespace sfgs {

// CIELAB's f(t): the cube root above (6/29)^3, its tangent-like linear branch at and below (the standard's).
inline constexpr double kLabLinearBelow = 216.0 / 24389.0;

}  // namespace sfgs
