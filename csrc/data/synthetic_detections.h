#pragma once
// What a whole-body keypoint detector (DWPose, RTMPose) would report for a synthetic frame: the exact keypoints of
// the posed body (body/wholebody_keypoints.h) projected with the frame's camera, then pixel noise that grows for
// small parts (a floor plus a share of the person's, face's or hand's size in the image), low scores and some
// dropped points where the body hides a keypoint from the camera, dropped points outside the image, and occasional
// outliers (a left/right confusion or a stray point). docs/fitting.md lists the numbers.
#include <ATen/core/Generator.h>
#include <ATen/core/Tensor.h>

#include "ops/splat/splat.h"

namespace sfgs::data {

struct DetectorNoise {
  bool exact = false;       // true: exact projections with score 1 (points outside the image still dropped)
  double floor_pixels;      // noise standard deviation every point has
  double body_share;        // plus this share of the person's height in the image (body and feet)
  double part_share;        // plus this share of the face's or the hand's own size in the image
  double outlier_rate;      // share of visible body, feet and hand points replaced by an outlier
  double hidden_drop_rate;  // share of hidden points dropped (score 0) rather than reported with a low score
  DetectorNoise();          // the defaults of constants.h
};

// (133, 3) [x, y, score] from `camera_keypoints` (133, 3) in the frame's camera coordinates (metres, OpenCV axes)
// seen by `camera` (its intrinsics; pixel (0, 0) covers [0, 1)^2), `depth` (H, W) the rendered camera-space depth of
// the body (0 where uncovered) and `on_surface` (133) bool (false: a joint inside the body, which hides behind a
// thicker layer before it counts as occluded). Dropped points have score 0 and lie clamped to the image.
at::Tensor simulate_detections(const at::Tensor& camera_keypoints, const Camera& camera, const at::Tensor& depth,
                               const at::Tensor& on_surface, const DetectorNoise& noise, at::Generator& gen);

}  // namespace sfgs::data
