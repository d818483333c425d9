#pragma once
#include <cstdint>

// The datasets' numbers, named once: the synthetic videos' key light.

namespace sfgs {

// ---- synthetic videos (docs/dataset_format.md, "Synthetic videos") ----------------------------------------------
// The key light's self-shadowing: the shadow map's side (pixels), the light's distance from the subject (in radii of
// its bounding sphere: far enough to be nearly parallel) and the depth bias (in radii) that keeps lit surfaces from
// shadowing themselves.
inline constexpr long kShadowMapSide = 1024;
inline constexpr double kShadowLightDistanceRadii = 40.0;
inline constexpr double kShadowBiasRadii = 0.01;
// Replay time (Dataset::replay_time): a frame replays its sequence when it lies within half the largest gap between
// the sequence's training times of one of them; this relative slack keeps frame times written in decimal seconds
// (7.9 s against a reach of 0.1 s) on the right side of the comparison.
inline constexpr double kReplayReachSlack = 1e-6;
// NeuMan's interleaved split (interleaved_split, dataset.h): of every 10 frames, offset 4 validates and offset 9 tests.
inline constexpr int64_t kInterleavedSplitPeriod = 10, kInterleavedValidationOffset = 4, kInterleavedTestOffset = 9;
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
// Spans and durations below this (seconds, or axis units of a plot) are treated as this, so nothing divides by zero
// and tick loops include their last tick despite rounding.
inline constexpr double kMinSpan = 1e-9;

}  // namespace sfgs
