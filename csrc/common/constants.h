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
// The rotation block R of a camera's world_to_camera must satisfy max |R R^T - I| <= this (and det R > 0): loose
// enough for rotations stored with 6-7 significant digits, tight enough to refuse scaled, sheared or singular ones.
inline constexpr double kCameraRotationTolerance = 1e-4;
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
// The CUDA forward blend cuts a tile's run longer than this many intersections into segments of this length, each
// composited by its own block and joined by the tile's last segment to finish (csrc/cuda/blend_forward.cu), so that
// the face's and hands' runs of thousands spread over many blocks. Measured on the avatars (bench_animate
// --blend-segments, docs/performance.md): shorter is faster down to 256 (one batch of the block), 2048 gains nothing.
inline constexpr long kBlendSegmentLength = 256;
// Largest accepted image side (pixels); larger images are refused with a clear error.
inline constexpr long kMaxImageSide = 16384;
// The CPU backend refuses a render whose Gaussians' tile rectangles add up to more tiles than this (the bound on its
// Gaussian-tile pairs, checked before the exact tile test): each pair costs 24 bytes of intersection lists and
// (7 + C) values of backward gradient slots, 104 bytes for RGB in float64, so this caps those at about 3.5 GB and the
// run time at minutes, not hours. The avatar workloads stay under a tenth of it (1M Gaussians at 1080 x 1920: 2.7M).
inline constexpr long kCpuMaxTilePairs = 1L << 25;

// ---- animation (csrc/animate, docs/performance.md) ---------------------------------------------------------
// A graph frame's splatting buffers are sized from a budget: the first guess per Gaussian, and the slack over the
// counts of a pass that fitted (a new pose may touch more tiles than the one the budget was taken from).
inline constexpr long kAnimatorInitialIntersectionsPerGaussian = 4;
inline constexpr double kAnimatorBudgetSlack = 1.5;
// The Animator can cull Gaussians whose posed normal faces away from the camera by more than a cosine (between the
// normal and the view ray; animate/visibility.h). Off by default (1): on a trained avatar it is lossy (0.3: the
// frame 9 % faster, but 38-42 dB against the exact render; docs/performance.md), because small Gaussians' opacity
// is scaled down by the antialiasing compensation and the near side does not hide the far side completely.
inline constexpr double kAnimatorBackFacingCosine = 1.0;
// A cosine that culls clearly back-facing Gaussians only, for callers who trade that accuracy for speed.
inline constexpr double kAnimatorFastBackFacingCosine = 0.3;

// ---- metrics (docs/metrics.md) -----------------------------------------------------------------------------
// Images are compared on values in [0, 1]: PSNR, SSIM's C1/C2 and LPIPS's 2v - 1 mapping assume this range.
inline constexpr double kImageDataRange = 1.0;
// SSIM as Wang et al. (2004) and every reference implementation we match: 11 x 11 Gaussian window, sigma 1.5,
// C1 = (K1 L)^2, C2 = (K2 L)^2.
inline constexpr int kSsimWindowSize = 11;
inline constexpr double kSsimSigma = 1.5;
inline constexpr double kSsimK1 = 0.01;
inline constexpr double kSsimK2 = 0.03;
// LPIPS v0.1 (richzhang/PerceptualSimilarity): the ScalingLayer's ImageNet shift and scale for R, G, B, and
// the epsilon added outside the square root when feature vectors are unit-normalised.
inline constexpr double kLpipsShift[3] = {-0.030, -0.088, -0.188};
inline constexpr double kLpipsScale[3] = {0.458, 0.448, 0.450};
inline constexpr double kLpipsNormEpsilon = 1e-10;
// Squared feature norms are floored here before the square root: where every channel of a tap is 0 (all ReLUs
// off), d sqrt(s)/ds is infinite and autograd would turn 0 * inf into NaN. The floor only acts where every
// feature is below 1e-15 and moves a normalised feature there by at most 1e-10.
inline constexpr double kLpipsMinSquaredNorm = 1e-30;
// A floating mask counts a pixel as inside when its value exceeds this (mask IoU of soft masks).
inline constexpr double kMaskInsideThreshold = 0.5;
// 8-bit images: a value v in [0, 1] is stored as v * kEightBitMax.
inline constexpr double kEightBitMax = 255.0;
// Nearest-neighbour search by brute force (the CUDA path) works on blocks of at most this many query-target
// distances, so 167k x 167k point sets need ~128 MB (float64) at a time instead of 224 GB.
inline constexpr long kNearestNeighbourBlockElements = 1L << 24;

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

// ---- avatar model (docs/avatar.md) ------------------------------------------------------------------------
// The feature planes are read at the points' positions in SFGS's star ("big") pose: both hips rotated this far
// (radians) about the forward axis, so the inner thighs no longer share plane texels.
inline constexpr double kStarPoseHipAngle = 1.0;
// A Gaussian's initial standard deviation is this fraction of the mean length of its mesh edges: neighbours
// overlap at about one standard deviation, so the initial surface renders closed.
inline constexpr double kInitialScaleEdgeFraction = 0.5;
// Standard deviation of the random initial plane features: non-zero so points differ from the first step (the
// authors start at zero), small so the MLPs start in their near-linear range.
inline constexpr double kPlaneInitStd = 0.1;
// GroupNorm of the authors' head MLPs: channel groups, and the epsilon of torch.nn.GroupNorm.
inline constexpr long kMlpGroupNormGroups = 4;
inline constexpr double kMlpGroupNormEpsilon = 1e-5;
// Hidden width of the MANO hand-residual MLP (the authors' 64).
inline constexpr long kHandResidualHiddenWidth = 64;
// The MANO shape fitted to the subject's SMPL-X hand should match it to millimetres; beyond this RMS (metres) the
// files are probably swapped or meant for another model, and the avatar warns.
inline constexpr double kHandFitWarningRms = 0.01;
// Summed face normals shorter than this (a vertex on degenerate faces only) give a zero vertex normal.
inline constexpr double kMinNormalLength = 1e-12;

// Observation prior (docs/avatar.md, "Surface the video never showed"). A Gaussian counts as observed in a training
// step when it faces the camera, projects into the image and lies no deeper than this (metres) behind the rendered
// depth at its pixel: thinner than a torso, wrist or head, thicker than the rendered depth's blur at an edge.
inline constexpr double kObservationDepthTolerance = 0.03;
// A Gaussian (or, in evaluation, a ground-truth vertex) is well observed when it was seen, front-facing, in at least
// this fraction of the training steps (frames); below it, its learned colour and offsets are trusted in proportion.
inline constexpr double kWellObservedFraction = 0.05;
// Per-region evaluation (docs/metrics.md): a region counts in a frame from this many pixels on; a region rendered
// exactly scores PSNR 10 log10(1 / this MSE) instead of infinity.
inline constexpr long kMinRegionPixels = 16;
inline constexpr double kMinRegionMse = 1e-10;
// Smoothing passes of the colours propagated into poorly observed surface, after the front from the observed
// surface has reached every point: enough to blend the propagated colours over a few mesh rings.
inline constexpr long kObservationSmoothingPasses = 16;
// Replay time (Dataset::replay_time): a frame replays its sequence when it lies within half the largest gap between
// the sequence's training times of one of them; this relative slack keeps frame times written in decimal seconds
// (7.9 s against a reach of 0.1 s) on the right side of the comparison.
inline constexpr double kReplayReachSlack = 1e-6;

// ---- training configuration (docs/training.md) ----------------------------------------------------------------
// Ranges a config's values must lie in. They refuse values that can only diverge or exhaust memory (a learning rate
// of 1e30, a loss weight whose product overflows float32, planes of a million texels a side), not unusual choices:
// the defaults sit orders of magnitude inside them (learning rates 1e-3, Laplacian weights 1e5, planes 128-256).
inline constexpr double kMaxLearningRate = 1.0;
inline constexpr double kMaxLossWeight = 1e9;
inline constexpr long kMaxIterations = 100000000;
inline constexpr long kMaxPlaneChannels = 1024;
inline constexpr long kMaxPlaneResolution = 4096;
inline constexpr long kMaxHiddenWidth = 4096;

// ---- synthetic videos (docs/dataset_format.md, "Synthetic videos") ----------------------------------------------
// The key light's self-shadowing: the shadow map's side (pixels), the light's distance from the subject (in radii of
// its bounding sphere: far enough to be nearly parallel) and the depth bias (in radii) that keeps lit surfaces from
// shadowing themselves.
inline constexpr long kShadowMapSide = 1024;
inline constexpr double kShadowLightDistanceRadii = 40.0;
inline constexpr double kShadowBiasRadii = 0.01;

// ---- export and plots -----------------------------------------------------------------------------------
// Covariance eigenvalues are clamped to this before their logarithm (the exported log scale of a flat Gaussian).
inline constexpr double kMinExportedVariance = 1e-20;
// Spans and durations below this (seconds, or axis units of a plot) are treated as this, so nothing divides by zero
// and tick loops include their last tick despite rounding.
inline constexpr double kMinSpan = 1e-9;

}  // namespace sfgs
