#pragma once
// The numbers every layer shares, named once: a quaternion's norm floor and the images' value conventions. Each module
// names its own in its constants.h (ops/splat/, ops/ssim/, ops/group_norm/, ops/pixel_loss/, ops/plane_sampling/,
// body/, model/, animate/, metrics/, data/, fit/, train/); host and device code include them, and nothing else writes
// these numbers as literals.

namespace sfgs {

// Quaternions shorter than this cannot be normalised: such a Gaussian is culled, not rendered with NaNs.
inline constexpr double kMinQuaternionNorm = 1e-12;
// Images are compared on values in [0, 1]: PSNR, SSIM's C1/C2 and LPIPS's 2v - 1 mapping assume this range.
inline constexpr double kImageDataRange = 1.0;
// 8-bit images: a value v in [0, 1] is stored as v * kEightBitMax.
inline constexpr double kEightBitMax = 255.0;

}  // namespace sfgs
