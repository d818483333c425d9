#pragma once
// Numerical thresholds of sfgs, named once: those of the splatting op, animation, metrics, the avatar model and
// fitting. The body models', the datasets' and training's own live in body/constants.h, data/constants.h and
// train/constants.h. Host and device code include these headers; nothing else writes these numbers as literals.

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
// composited by its own block and joined by the tile's last segment to finish (csrc/ops/splat/cuda/blend_forward.cu),
// so that the face's and hands' runs of thousands spread over many blocks. Measured on the avatars (bench_animate
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
// A recorded frame's or training step's splatting buffers are sized from a budget: the first guess per Gaussian, and
// the slack over the counts of a pass that fitted (a new pose may touch more tiles than the one the budget was taken
// from).
inline constexpr long kGraphInitialIntersectionsPerGaussian = 4;
inline constexpr double kGraphBudgetSlack = 1.5;
// Recorded training steps the host queues before it reads the splatting counts of the oldest (train/step_graphs.h):
// two, so it reads a step while the GPU runs the next and never waits for the step it has just queued.
inline constexpr long kGraphUncheckedSteps = 2;
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
// The fused SSIM's CUDA kernels (ops/ssim/ssim.h) filter tiles of 32 columns and this many rows of one channel in
// shared memory; a tile reads its rows plus 10 of halo, so taller tiles re-read less, and 16 keeps a float32 block
// within 26 KiB. float64 (the parity tests) takes half as many rows, within the 48 KiB of static shared memory.
inline constexpr int kSsimTileRows = 16;
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

// ---- avatar model (docs/avatar.md) ------------------------------------------------------------------------
// The planes' backward (ops/plane_sampling/plane_sampling.h) sums the reads of one texel in chunks of at most this
// many, one warp each: a texel thousands of points read does not hold up the kernel (the last warp) behind it.
inline constexpr long kPlaneReadChunk = 32;
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
// The fused GroupNorm + ReLU kernel (ops/group_norm/group_norm.h) keeps a row in one warp's registers, at most 8 values
// a lane: the avatar's widths (64-256) fit; wider rows take the LibTorch composition.
inline constexpr long kGroupNormMaxChannels = 256;
// CIELAB's f(t): the cube root above (6/29)^3, its tangent-like linear branch at and below (the standard's).
inline constexpr double kLabLinearBelow = 216.0 / 24389.0;
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

// ---- whole-body keypoints, noisy fits, fitting (docs/fitting.md) ------------------------------------------
// A landmark embedding's barycentric coordinates must sum to 1 within this (files store them in float32).
inline constexpr double kBarycentricSumTolerance = 1e-3;
// `sfgs synth --pose-noise medium` (low halves every number, high doubles it): RMS rotation error of each body joint
// (degrees), of each wrist and finger joint, of the global orientation; RMS translation error across the view (cm,
// per axis) and along it (depth, which one view measures worst); the shape error per coefficient; the share of
// frames whose hands are exchanged (none at low). Roughly what image-based SMPL-X regressors leave on easy footage.
inline constexpr double kPoseNoiseMediumBodyDegrees = 5.0;
inline constexpr double kPoseNoiseMediumHandDegrees = 10.0;
inline constexpr double kPoseNoiseMediumRootDegrees = 4.0;
inline constexpr double kPoseNoiseMediumLateralCm = 2.0;
inline constexpr double kPoseNoiseMediumDepthCm = 6.0;
inline constexpr double kPoseNoiseMediumBetasSigma = 0.25;
inline constexpr double kPoseNoiseMediumHandSwapRate = 0.02;
// Every level: the share of each error's variance that is frame-to-frame jitter (the rest drifts), and the drift's
// correlation time (seconds).
inline constexpr double kPoseNoiseJitterShare = 0.3;
inline constexpr double kPoseNoiseDriftSeconds = 1.0;
// Seeds of a synthetic video's independent random streams (shape, fit noise, detections) lie this far apart.
inline constexpr unsigned long long kSeedStreamStride = 0x9E3779B97F4A7C15ull;
// Synthetic detections (data/synthetic_detections.h): pixel noise = floor + a share of the person's height (body,
// feet) or of the face's / hand's own size in the image, so small parts are relatively noisier; hidden points get
// this many times the noise. Scores are uniform in these ranges for visible, hidden and outlier points.
inline constexpr double kDetectorNoiseFloorPixels = 1.5;
inline constexpr double kDetectorNoiseBodyShare = 0.01;
inline constexpr double kDetectorNoisePartShare = 0.04;
inline constexpr double kDetectorHiddenNoiseFactor = 3.0;
inline constexpr double kDetectorOutlierRate = 0.02;
inline constexpr double kDetectorHiddenDropRate = 0.3;
inline constexpr double kDetectorVisibleScore[2] = {0.7, 0.98};
inline constexpr double kDetectorHiddenScore[2] = {0.1, 0.5};
inline constexpr double kDetectorOutlierScore[2] = {0.4, 0.8};
// A keypoint is hidden when it lies farther than this (metres) behind the rendered surface at its pixel: a surface
// point (nose, fingertip, landmark) must be on the visible surface, a joint sits inside its limb.
inline constexpr double kSurfaceKeypointOcclusionDepth = 0.03;
inline constexpr double kJointKeypointOcclusionDepth = 0.1;

// `sfgs fit` (csrc/fit, docs/fitting.md). Adam steps per stage (global orientation and translation; body and shape;
// hands, jaw and expression; the silhouette stage where masks exist) and progress lines every this many steps. The
// body stage is still settling the limbs' depths at 300 steps: 600 body and 300 detail steps took the benchmark's
// root-aligned MPJPE from 39.7 to 34.4 mm (sway) and 42.9 to 41.5 mm (walk) for half as much time again (60 frames:
// 12 -> 18 s on one core); the detail stage (every keypoint, the body still moving) keeps settling them too: 600
// detail and 200 silhouette steps took sway / walk / wave from 31.7 / 37.4 / 66.8 to 28.0 / 35.5 / 64.2 mm for
// two thirds more time (60 frames: 18 -> 31 s on one core); on today's synthetic clips (30.4 / 35.4 / 65.3 mm at 600)
// 1,200 detail steps give 28.0 / 33.5 / 64.7 mm (vertices 39.2 -> 35.4 mm on sway) for about 10 s more, where 1,800
// gain nothing more (28.4 on sway; docs/fitting.md).
inline constexpr long kFitGlobalIterations = 80;
inline constexpr long kFitBodyIterations = 600;
inline constexpr long kFitDetailIterations = 1200;
inline constexpr long kFitSilhouetteIterations = 200;
inline constexpr long kFitLogEvery = 25;
// Intra-op threads of a CPU fit (fit.h FitOptions::threads says why one).
inline constexpr long kFitCpuThreads = 1;
// Shape and expression coefficients fitted (what `sfgs synth` animates and the avatar reads by default).
inline constexpr long kFitBetas = 10;
inline constexpr long kFitExpressions = 10;
// Detections scoring below this are ignored (DWPose's usual visualisation threshold); scores count up to 1.
inline constexpr double kFitMinKeypointScore = 0.3;
// Residuals are divided by the person's size in the image (the diagonal of the confident keypoints' box, at least
// this many pixels), so the weights below hold at any resolution.
inline constexpr double kFitMinPersonPixels = 16.0;
// The start: upright orientations tried per frame; the ridge on the translation's normal equations; candidates
// placing the body nearer than this (metres) are refused; a frame with fewer torso or head detections than this
// starts facing the camera at the depth a body of this height (metres) would have.
inline constexpr long kFitOrientationCandidates = 12;
inline constexpr double kFitInitialRidge = 1e-6;
inline constexpr double kFitMinInitialDepth = 0.3;
inline constexpr long kFitMinInitialKeypoints = 3;
inline constexpr double kFitAssumedBodyHeight = 1.7;
// Adam's step (radians, metres; shape and expression coefficients take this factor more), falling linearly to the
// share at each stage's end; the silhouette stage only settles.
inline constexpr double kFitLearningRate = 0.03;
inline constexpr double kFitSilhouetteLearningRate = 0.005;
inline constexpr double kFitCoefficientRateFactor = 2.0;
inline constexpr double kFitFinalLearningRateShare = 0.1;
// Geman-McClure scales of the keypoint residuals (shares of the person's size): 10 % in the global, body and detail
// stages (a detector's body noise is 1-2 % of the person's size, but a limb still on the wrong side of its depth
// ambiguity sits farther than 5 % from its detections, and a narrower scale stops those from pulling it over), then
// 5 % in the silhouette stage, which only settles a body already close: farther detections count as outliers.
inline constexpr double kFitGlobalRobustSigma = 0.1;
inline constexpr double kFitRobustSigma = 0.1;
inline constexpr double kFitSilhouetteRobustSigma = 0.05;
// Each stage starts nearly quadratic (this scale: every detection pulls, however far, and limbs start far from
// theirs) and narrows geometrically to its own scale over this share of its steps.
inline constexpr double kFitInitialRobustSigma = 0.2;
inline constexpr double kFitRobustAnnealShare = 0.5;
// Keypoint weights per group (body 1, hands 1): feet, the face's 68 landmarks in the detail stages and, for the
// head's orientation only, in the body stage.
inline constexpr double kFitFeetWeight = 0.5;
inline constexpr double kFitFaceWeight = 0.3;
inline constexpr double kFitBodyStageFaceWeight = 0.05;
// Prior weights, against keypoint residuals squared in units of the person's size: body joints' axis-angles (with
// hinges this many times stronger on impossible knee and elbow bends), hands towards the mean hand, shape,
// expression and jaw towards zero.
inline constexpr double kFitBodyPriorWeight = 3e-3;
inline constexpr double kFitJointLimitWeight = 100.0;
// The body prior's centre has the arms hanging, each shoulder turned this far (radians) down from the T-pose; twists
// about a limb's own axis, which one view sees least, weigh this many times a swing; the flexion of knees and
// elbows is free within its limits (an L2 pull would straighten them and let the hip or shoulder take the bend,
// which one view cannot tell apart).
inline constexpr double kFitHangingArmAngle = 1.2;
inline constexpr double kFitTwistPriorFactor = 4.0;
// Joints that move little in most motions weigh more in the body prior, the shoulders (the widest range) less: an
// even prior lets the optimiser lean the spine (three joints sharing a bend) where the arm should have turned.
inline constexpr double kFitSpinePriorFactor = 30.0;      // spine1-3, neck, collars
inline constexpr double kFitSpineTwistPriorFactor = 3.0;  // but a spine joint's twist
inline constexpr double kFitShoulderPriorFactor = 0.3;
// A hip's flexion (a leg swinging forwards or backwards, along the view when the subject faces the camera) weighs
// this share of a swing: one view sees such a swing as a small change of the leg's length in the image, and the full
// weight held a walk's 30-degree swings halfway to rest (MPJPE 41.5 -> 37.4 mm walk, 34.4 -> 31.7 mm sway).
inline constexpr double kFitHipFlexionPriorFactor = 0.3;
inline constexpr double kFitHandPriorWeight = 1e-4;
// The shape prior is 10 times the other coefficient priors: one view fixes size and depth only together, and a
// weaker pull let the fitted limbs shrink by 3-5 % (the subject nearer the camera, the limbs' depths wrong).
inline constexpr double kFitShapePriorWeight = 1e-3;
inline constexpr double kFitExpressionPriorWeight = 1e-4;
inline constexpr double kFitJawPriorWeight = 1e-4;
// Temporal smoothness: Geman-McClure of the acceleration of every keypoint and joint between consecutive frames
// (metres per frame^2: a cut or a fast swing beyond the scale stops being smoothed).
inline constexpr double kFitTemporalWeight = 0.1;
inline constexpr double kFitTemporalSigma = 0.05;
// Silhouette term (fit/silhouette.h): its weight, the masks' reduced side (pixels) for the distance transform, the
// boundary samples per frame and their seed, and the surface vertices sampled.
inline constexpr double kFitSilhouetteWeight = 1.0;
inline constexpr long kFitSilhouetteSide = 160;
inline constexpr long kFitSilhouetteBoundarySamples = 256;
inline constexpr unsigned long long kFitSilhouetteSeed = 1;
inline constexpr long kFitSilhouetteVertices = 800;
// Frames per SMPL-X evaluation when measuring a fit's accuracy (bounds memory on long videos).
inline constexpr long kFitAccuracyChunk = 32;

// Spans and durations below this (seconds, or axis units of a plot) are treated as this, so nothing divides by zero
// and tick loops include their last tick despite rounding.
inline constexpr double kMinSpan = 1e-9;

}  // namespace sfgs
