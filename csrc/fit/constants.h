#pragma once
// The keypoint fitter's numbers, named once (docs/fitting.md).

namespace sfgs {

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

}  // namespace sfgs
