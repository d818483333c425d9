#pragma once
// The Animator's numbers, named once.
#include <cstdint>

namespace sfgs {

// The Animator can cull Gaussians whose posed normal faces away from the camera by more than a cosine (between the
// normal and the view ray; animate/visibility.h). Off by default (1): on a trained avatar it is lossy (0.3: the
// frame 9 % faster, but 38-42 dB against the exact render; docs/performance.md), because small Gaussians' opacity
// is scaled down by the antialiasing compensation and the near side does not hide the far side completely.
inline constexpr double kAnimatorBackFacingCosine = 1.0;
// A cosine that culls clearly back-facing Gaussians only, for callers who trade that accuracy for speed.
inline constexpr double kAnimatorFastBackFacingCosine = 0.3;

// A batch of frames (animate/batch_animator.h) is rendered by at most this many Animators at once, each replaying its
// graph on a stream of its own: one frame's short kernels leave the GPU partly idle, and the others fill it. Each
// lane holds its own recording and buffers (about a frame's memory).
inline constexpr int64_t kBatchLanes = 4;

}  // namespace sfgs
