#pragma once
// Temporal smoothing of a video's fits (pose refinement, docs/training.md "Imperfect fits"). A pose estimator's error
// is partly frame-to-frame jitter, and the image cannot pull out of a fit the jitter of a joint it barely shows, while
// a body moves smoothly: an avatar trained on jittering fits blurs over the jitter. Each frame's fit is replaced by a
// local quadratic regression over the fits of its sequence's frames near it in time, Gaussian-weighted (standard
// deviation sigma_seconds, out to kFitSmoothingWindowSigmas of it). A quadratic regression keeps what moves with a
// steady acceleration (a wave, a turn) where a weighted mean would flatten its peaks; rotations are regressed in the
// tangent space at the frame's own rotation, so joints near a half turn (a camera-frame root) smooth like any other.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

#include "train/constants.h"

namespace sfgs::train {

// `fits`: (F, 3 R + L) rows, R axis-angles then L values that move linearly (a translation); `times` (seconds) and
// `sequences` per row. Returns the smoothed rows, same shape, dtype and device. Frames of different sequences never
// mix; a frame with no other frame of its sequence within the window keeps its fit. Each smoothed axis-angle is the
// representative of its rotation nearest the row's own (an estimator's 3.1 rad about x stays near 3.1, not -3.18).
at::Tensor smooth_fits(const at::Tensor& fits, int64_t rotations, const std::vector<double>& times,
                       const std::vector<int64_t>& sequences, double sigma_seconds);

}  // namespace sfgs::train
