#pragma once
// The plane sampling's numbers, named once.

namespace sfgs {

// The planes' backward (ops/plane_sampling/plane_sampling.h) sums the reads of one texel in chunks of at most this
// many, one warp each: a texel thousands of points read does not hold up the kernel (the last warp) behind it.
inline constexpr long kPlaneReadChunk = 32;

}  // namespace sfgs
