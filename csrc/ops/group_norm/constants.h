#pragma once
// The fused GroupNorm's numbers, named once.

namespace sfgs {

// The fused GroupNorm + ReLU kernel (ops/group_norm/group_norm.h) keeps a row in one warp's registers, at most 8 values
// a lane: the avatar's widths (64-256) fit; wider rows take the LibTorch composition.
inline constexpr long kGroupNormMaxChannels = 256;

}  // namespace sfgs
