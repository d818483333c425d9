#pragma once
// Mathematical constants (C++17 has no std::numbers).

namespace sfgs {

inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kTwoPi = 2.0 * kPi;

}  // namespace sfgs
