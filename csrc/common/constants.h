#pragma once
// Every numerical threshold of sfgs, named once. Host and device code include this header; nothing else
// in the project writes these numbers as literals.

namespace sfgs {

// ---- splatting: projection --------------------------------------------------------------------------------
// Variance (px^2) added to every projected 2D covariance: the EWA low-pass filter that keeps sub-pixel
// Gaussians at least one pixel wide so they cannot alias or vanish between pixel centres.
inline constexpr double kLowPassVariancePx2 = 0.3;
// Floor of the antialiasing opacity compensation sqrt(det(S)/det(S + low-pass)): without it a Gaussian
// much thinner than a pixel would be compensated to zero opacity and stop receiving gradients.
inline constexpr double kMinCompensation = 0.005;
// Jacobian of the perspective projection is evaluated at most this fraction of the half field of view outside
// the image: far off-axis Gaussians otherwise get huge, meaningless screen footprints (EWA linearisation).
inline constexpr double kFovGuardFraction = 0.3;
// A projected 2D covariance counts as positive semi-definite when det >= -kPsdTolerance * a * c: rounding
// makes the determinant of exactly singular (flat) covariances slightly negative.
inline constexpr double kPsdTolerance = 1e-6;
// Determinant (px^4) below which a dilated 2D covariance is treated as degenerate and the Gaussian culled.
inline constexpr double kMinDeterminant2D = 1e-12;
// Relative slack on the ellipse level in the tile test: a pixel whose alpha is within rounding of kMinAlpha
// must never be dropped by the tile test in one backend and kept in the other.
inline constexpr double kTileTestSlack = 1e-4;
// Pixel centres sit at integer + 0.5 (COLMAP / OpenCV-continuous convention): pixel (0,0) covers [0,1)^2.
inline constexpr double kPixelCentre = 0.5;
// Defaults for the camera's clipping range (metres, along the optical axis).
inline constexpr double kDefaultNearPlane = 0.01;
inline constexpr double kDefaultFarPlane = 1e10;
// Quaternions shorter than this cannot be normalised: such a Gaussian is culled, not rendered with NaNs.
inline constexpr double kMinQuaternionNorm = 1e-12;

// ---- splatting: blending -----------------------------------------------------------------------------------
// Pixel-Gaussian pairs with alpha below one 8-bit level are skipped.
inline constexpr double kMinAlpha = 1.0 / 255.0;
// Alpha is capped so 1 - alpha never vanishes; (1 - 0.99)^2 = kMinTransmittance.
inline constexpr double kMaxAlpha = 0.99;
// A pixel stops blending when the next Gaussian would take its transmittance below this; that Gaussian is
// excluded, so the backward pass never divides by a transmittance this small.
inline constexpr double kMinTransmittance = 1e-4;
// Side of the square screen tiles (pixels). Kernels assume 16 x 16 = 256 threads per tile.
inline constexpr int kTileSize = 16;
// Largest accepted image side (pixels); larger images are refused with a clear error.
inline constexpr long kMaxImageSide = 16384;

}  // namespace sfgs
