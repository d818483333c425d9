#pragma once
// The metrics' numbers, named once: LPIPS, masks, nearest-neighbour search.

namespace sfgs {

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
// Nearest-neighbour search by brute force (the CUDA path) works on blocks of at most this many query-target
// distances, so 167k x 167k point sets need ~128 MB (float64) at a time instead of 224 GB.
inline constexpr long kNearestNeighbourBlockElements = 1L << 24;

}  // namespace sfgs
