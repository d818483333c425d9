#pragma once
// The splatting op's numbers, named once: projection, blending, the CPU backend's limits and the
// budget of a recorded pass.

namespace sfgs {

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
// The rotation block R of a camera's world_to_camera must satisfy max |R R^T - I| <= this (and det R > 0): loose
// enough for rotations stored with 6-7 significant digits, tight enough to refuse scaled, sheared or singular ones.
inline constexpr double kCameraRotationTolerance = 1e-4;
// Pixel-Gaussian pairs with alpha below one 8-bit level are skipped.
inline constexpr double kMinAlpha = 1.0 / 255.0;
// Alpha is capped so 1 - alpha never vanishes; (1 - 0.99)^2 = kMinTransmittance.
inline constexpr double kMaxAlpha = 0.99;
// A pixel stops blending when the next Gaussian would take its transmittance below this; that Gaussian is
// excluded, so the backward pass never divides by a transmittance this small.
inline constexpr double kMinTransmittance = 1e-4;
// Side of the square screen tiles (pixels). Kernels assume 16 x 16 = 256 threads per tile.
inline constexpr int kTileSize = 16;
// The CUDA forward blend cuts a tile's run longer than this many intersections into segments of this length, each
// composited by its own block and joined by the tile's last segment to finish (csrc/ops/splat/cuda/blend_forward.cu),
// so that the face's and hands' runs of thousands spread over many blocks. Measured on the Anny avatar (bench_animate
// --blend-segments, docs/performance.md): 128 and 256 (one batch of the block) give the same frame, 64 and 512 are
// slower.
inline constexpr long kBlendSegmentLength = 256;
// Largest accepted image side (pixels); larger images are refused with a clear error.
inline constexpr long kMaxImageSide = 16384;
// The CPU backend refuses a render whose Gaussians' tile rectangles add up to more tiles than this (the bound on its
// Gaussian-tile pairs, checked before the exact tile test): each pair costs 24 bytes of intersection lists and
// (7 + C) values of backward gradient slots, 104 bytes for RGB in float64, so this caps those at about 3.5 GB and the
// run time at minutes, not hours. The avatar workloads stay under a tenth of it (1M Gaussians at 1080 x 1920: 2.7M).
inline constexpr long kCpuMaxTilePairs = 1L << 25;
// A recorded frame's or training step's splatting buffers are sized from a budget: the first guess per Gaussian, and
// the slack over the counts of a pass that fitted (a new pose may touch more tiles than the one the budget was taken
// from).
inline constexpr long kGraphInitialIntersectionsPerGaussian = 4;
inline constexpr double kGraphBudgetSlack = 1.5;

}  // namespace sfgs
