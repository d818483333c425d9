#pragma once
// The avatar model's numbers, named once: initialisation, networks, the observation prior.

namespace sfgs {

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
// Observation prior (docs/avatar.md, "Surface the video never showed"). A Gaussian counts as observed in a training
// step when it faces the camera, projects into the image and lies no deeper than this (metres) behind the rendered
// depth at its pixel: thinner than a torso, wrist or head, thicker than the rendered depth's blur at an edge.
inline constexpr double kObservationDepthTolerance = 0.03;
// A Gaussian (or, in evaluation, a ground-truth vertex) is well observed when it was seen, front-facing, in at least
// this fraction of the training steps (frames); below it, its learned colour and offsets are trusted in proportion.
inline constexpr double kWellObservedFraction = 0.05;
// Smoothing passes of the colours propagated into poorly observed surface, after the front from the observed
// surface has reached every point: enough to blend the propagated colours over a few mesh rings.
inline constexpr long kObservationSmoothingPasses = 16;

}  // namespace sfgs
