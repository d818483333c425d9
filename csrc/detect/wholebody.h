#pragma once
// MediaPipe's landmarks as COCO-WholeBody's 133 keypoints (the format `sfgs fit` reads, docs/fitting.md).
#include <ATen/core/Tensor.h>

#include "detect/parts.h"
#include "detect/pose_tracker.h"

namespace sfgs::detect {

inline constexpr int64_t kWholeBodyKeypoints = 133;

// (133, 3) [x, y, score] on the CPU. The body (0-16) and feet (17-22) come from the pose landmarks, each scored by its
// visibility (the small toes have no landmark: score 0; the big toes are the feet's tips); the face (23-90, iBUG-68
// order) from the face mesh by a fixed correspondence (docs/prepare.md), and each hand (91-111 left, 112-132 right)
// one to one from its 21 landmarks, scored by their network's presence. A part not found scores 0.
at::Tensor wholebody_keypoints(const PoseFrame& pose, const PartLandmarks& face, const PartLandmarks& left_hand,
                               const PartLandmarks& right_hand);

}  // namespace sfgs::detect
