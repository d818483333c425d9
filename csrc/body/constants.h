#pragma once
// The body models' numbers, named once: rotation conversions and the body layers' tolerances.

namespace sfgs {

// ---- body models (docs/body_models.md) --------------------------------------------------------------------
// Below this rotation angle (radians) axis-angle <-> matrix conversions use Taylor series (to 8th order, exact
// in float64) instead of sin(t)/t and atan2(n, w)/n, whose float32 gradients lose their digits to cancellation.
inline constexpr double kRotationSeriesAngle = 0.1;
// Norms below this count as zero when the 6D rotation representation is orthonormalised (Gram-Schmidt).
inline constexpr double kMinRotation6dNorm = 1e-12;
// Skinning weights of a loaded model should sum to 1 per vertex within this tolerance (official files: ~1e-7);
// beyond it loading warns.
inline constexpr double kSkinningWeightSumTolerance = 1e-4;
// The official MANO_LEFT shares its shapedirs x components with MANO_RIGHT (vchoutas/smplx#48): when the two
// agree within this fraction of the right model's sum |shapedirs[:, 0, :]|, the left x components are negated.
inline constexpr double kManoLeftShapedirsBugTolerance = 1e-6;
// Procedural body UVs: a triangle corner closer to its cylinder chart's axis than this fraction of the chart's mean
// radius has no defined angle around it; it takes the angle of its triangle's centre and a UV row of its own.
inline constexpr double kUvPoleRadiusFraction = 1e-6;
// Procedural hand pose basis: Gram-Schmidt drops a candidate whose remainder is shorter than this, as it lies in
// the span of the rows already taken (unit candidates leave either about 1 or rounding noise of about 1e-16).
inline constexpr double kMinHandPoseBasisNorm = 1e-6;
// Procedural cheek-puff direction: horizontal distances from the head's centre are floored here before they divide,
// so a vertex on the vertical line through the centre gets a zero direction instead of NaN.
inline constexpr double kMinCheekPuffRadialLength = 1e-9;
// Summed face normals shorter than this (a vertex on degenerate faces only) give a zero vertex normal.
inline constexpr double kMinNormalLength = 1e-12;
// A landmark embedding's barycentric coordinates must sum to 1 within this (files store them in float32).
inline constexpr double kBarycentricSumTolerance = 1e-3;

}  // namespace sfgs
