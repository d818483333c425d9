#pragma once
// The SSIM's numbers, named once (the fused op and the metric share them).

namespace sfgs {

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

}  // namespace sfgs
