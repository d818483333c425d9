#pragma once
// MediaPipe's landmarks as COCO-WholeBody's 133 keypoints (the format `sfgs fit` reads, docs/fitting.md).
#include <ATen/core/Tensor.h>

#include "detect/pose_tracker.h"

namespace sfgs::detect {

inline constexpr int64_t kWholeBodyKeypoints = 133;

// (133, 3) [x, y, score] on the CPU: the body (0-16) and feet (17-22) from the pose landmarks, each scored by its
// visibility; the small toes have no landmark and the big toes are the feet's tips. Face and hands are left at score
// 0 (not yet detected). A frame without a person gives all zeros.
at::Tensor wholebody_keypoints(const PoseFrame& pose);

}  // namespace sfgs::detect
