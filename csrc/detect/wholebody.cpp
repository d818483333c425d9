#include "detect/wholebody.h"

#include <ATen/ATen.h>

namespace sfgs::detect {
namespace {

// COCO-WholeBody index -> MediaPipe pose landmark, -1 for none (docs/prepare.md).
constexpr int kBodyAndFeet[23] = {0,  2,  5,  7,  8,        // nose, left eye, right eye, left ear, right ear
                                  11, 12, 13, 14, 15, 16,   // shoulders, elbows, wrists (left, right)
                                  23, 24, 25, 26, 27, 28,   // hips, knees, ankles
                                  31, -1, 29, 32, -1, 30};  // left big toe (foot tip), small toe, heel; right likewise
constexpr int kVisibility = 3;                              // the landmark column scored as COCO's confidence

}  // namespace

at::Tensor wholebody_keypoints(const PoseFrame& pose) {
  at::Tensor out = at::zeros({kWholeBodyKeypoints, 3});
  if (!pose.found) return out;
  const at::Tensor l = pose.landmarks.to(at::kCPU, at::kFloat).contiguous();
  for (int64_t k = 0; k < 23; ++k) {
    const int m = kBodyAndFeet[k];
    if (m < 0) continue;
    out[k][0] = l[m][0];
    out[k][1] = l[m][1];
    out[k][2] = l[m][kVisibility];
  }
  return out;
}

}  // namespace sfgs::detect
