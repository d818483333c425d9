#pragma once
// The datasets' numbers, named once: the synthetic videos' key light.

namespace sfgs {

// ---- synthetic videos (docs/dataset_format.md, "Synthetic videos") ----------------------------------------------
// The key light's self-shadowing: the shadow map's side (pixels), the light's distance from the subject (in radii of
// its bounding sphere: far enough to be nearly parallel) and the depth bias (in radii) that keeps lit surfaces from
// shadowing themselves.
inline constexpr long kShadowMapSide = 1024;
inline constexpr double kShadowLightDistanceRadii = 40.0;
inline constexpr double kShadowBiasRadii = 0.01;

}  // namespace sfgs
