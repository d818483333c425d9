#pragma once
// The training's numbers, named once: the configuration's defaults and ranges, the frame cache, and export's.

#include <cstddef>

namespace sfgs {

// ---- training configuration (docs/training.md) ----------------------------------------------------------------
// Training frames kept decoded in memory (8-bit) up to this many bytes (train/frame_cache.h); beyond it they are
// read from disk when drawn.
inline constexpr long kFrameCacheBytes = 2L << 30;
// Ranges a config's values must lie in. They refuse values that can only diverge or exhaust memory (a learning rate
// of 1e30, a loss weight whose product overflows float32, planes of a million texels a side), not unusual choices:
// the defaults sit orders of magnitude inside them (learning rates 1e-3, Laplacian weights 1e5, planes 128-256).
inline constexpr double kMaxLearningRate = 1.0;
// Loss evaluations (a render and its gradient) per frame of test-time fitting (`sfgs eval --fit-iterations`): with
// L-BFGS, exact-fit Anny avatar on medium-level test fits at 540 x 960, 300 reach 33.7 dB of the 34.9 exact test fits
// give (docs/archive/results-history.md, "L-BFGS"); 600 gave 33.0 at the earlier stage shares against 32.1-32.7 at 300,
// within the runs' spread, at twice the time.
inline constexpr long kPoseFitIterations = 300;
// Fitting a pose to an image with the avatar frozen (train/pose_fit.h): L-BFGS with a strong-Wolfe line search in
// three stages, each a share of the evaluations. Coarse: the global orientation and translation at 1/4 of the
// resolution (a 4 px blur widens the basin to the centimetres of an estimator's depth and lateral error, on 16 x fewer
// pixels); middle: every joint at 1/2; fine: every joint at full resolution. L-BFGS converges where the image is
// sharp, so most of the budget goes to the fine stage: shares of 0.3 / 0.3 measured 1-1.6 dB below 0.05 / 0.1 on the
// benchmark above, and with keypoints the coarse stages could go (33.8 dB without them), but without keypoints they
// are what reaches a far start.
inline constexpr double kPoseFitCoarseShare = 0.05;
inline constexpr long kPoseFitCoarseDownsample = 4;
inline constexpr double kPoseFitMiddleShare = 0.1;
inline constexpr long kPoseFitMiddleDownsample = 2;
// Curvature pairs L-BFGS keeps: enough to model how the 53 corrected rotations couple along the kinematic chain
// (what Adam, moving each number on its own, could not resolve: 29.4 dB on the benchmark above).
inline constexpr long kPoseFitHistory = 20;
// Fewest evaluations a coarser stage runs with: one would render once and never step (its share goes to the fine
// stage).
inline constexpr long kPoseFitMinStageEvaluations = 2;
// A fit with a person mask compares a crop around the person, not the whole image: the white rest costs the image
// terms (SSIM, LPIPS) per pixel as much as the person does. The mask's box is widened on each side by
// kPoseFitCropMargin of its larger side, where a misplaced body still shows (0.15 of a 1.7 m person is 25 cm), and its
// sides are rounded up to multiples of kPoseFitCropStep pixels, so that a video's crops come in few sizes and so few
// recorded graphs.
inline constexpr double kPoseFitCropMargin = 0.15;
inline constexpr long kPoseFitCropStep = 64;
// Weight of the silhouette term, the mean |alpha - person mask|, beside the image L1 of the downsampled stages: a
// share of misplaced pixels weighs about as much as the image error over them, and it pulls where the image is flat
// (white on white). The fine stage's is lighter: there the image inside the person decides, and the avatar's own
// soft edges would otherwise pull an exact fit away.
inline constexpr double kPoseFitSilhouetteWeight = 1.0;
inline constexpr double kPoseFitFineSilhouetteWeight = 0.1;
// Weight of the whole-body keypoint reprojection term (train/avatar_keypoints.h) beside every stage's image loss when
// the frame has detections: they pull a far start into the image's basin and pin the placement a frontal image sees
// poorly (with L-BFGS, 32.1-32.7 dB against 31.8 for the image alone; docs/results.md). At the robust term's scale a
// body within a detector's noise costs about 0.01.
inline constexpr double kPoseFitKeypointWeight = 1.0;
// Temporal smoothing of fits (train/fit_smoothing.h, pose_refinement.smoothing_seconds): how far the window reaches
// (in standard deviations of its Gaussian) and the local polynomial's degree. 2: a steady acceleration passes
// unchanged (on an exact waving motion a weighted mean moved the joints 0.26 deg, the quadratic 0.09).
inline constexpr double kFitSmoothingWindowSigmas = 3.0;
inline constexpr long kFitSmoothingOrder = 2;
// Below this angle (radians) an axis-angle has no other representative worth taking.
inline constexpr double kFitSmoothingSmallAngle = 1e-9;
// The longest smoothing a config may ask for (seconds): beyond a video's length it fits one quadratic to the whole.
inline constexpr double kMaxFitSmoothingSeconds = 3600.0;
// The most training rounds a config may ask for (pose_refinement.rounds): each is a whole training run; on the GPU
// benchmark a third round already lost to the second.
inline constexpr long kMaxPoseRefinementRounds = 8;
inline constexpr double kMaxLossWeight = 1e9;
inline constexpr long kMaxIterations = 100000000;
inline constexpr long kMaxPlaneChannels = 1024;
inline constexpr long kMaxPlaneResolution = 4096;
inline constexpr long kMaxHiddenWidth = 4096;

// ---- export and plots -----------------------------------------------------------------------------------
// Covariance eigenvalues are clamped to this before their logarithm (the exported log scale of a flat Gaussian).
inline constexpr double kMinExportedVariance = 1e-20;
// The web viewer (docs/web_viewer.md) skins each Gaussian with at most this many joints, its strongest, weights
// renormalised; the per-frame mean offsets carry what the others add, so only covariances and normals see the cut.
inline constexpr long kWebViewerInfluences = 4;
// The web export's data scripts hold at most about this many bytes each (before base64; a file holds at least one
// frame): a script of about 45 MB of base64 text, which browsers parse as one string literal without trouble.
inline constexpr long kWebDataFileBytes = 32L << 20;
// Recorded training steps the host queues before it reads the splatting counts of the oldest (train/step_graphs.h):
// two, so it reads a step while the GPU runs the next and never waits for the step it has just queued.
inline constexpr long kGraphUncheckedSteps = 2;
// Per-region evaluation (docs/metrics.md): a region counts in a frame from this many pixels on; a region rendered
// exactly scores PSNR 10 log10(1 / this MSE) instead of infinity.
inline constexpr long kMinRegionPixels = 16;
inline constexpr double kMinRegionMse = 1e-10;
// `sfgs eval` renders this many frames back to back and keeps them on the device (about 15 MB a frame at 800 x 1200)
// before it compares them on the CPU.
inline constexpr size_t kFramesRenderedAhead = 16;

}  // namespace sfgs
