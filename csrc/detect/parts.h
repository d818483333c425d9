#pragma once
// The face and the hands of MediaPipe Holistic (docs/prepare.md), found from the body's landmarks of the same frame:
// each hand's region from the pose's wrist, index and pinky, refined by the re-crop network, then 21 hand landmarks;
// the face's region from the pose's face points, a face detection inside it, then 468 face-mesh landmarks. Each frame
// is found afresh (MediaPipe also follows the previous frame's hand and face regions).
#include <ATen/core/Tensor.h>

#include "detect/pose_tracker.h"
#include "detect/region.h"
#include "detect/ssd.h"
#include "detect/tflite_network.h"

namespace sfgs::detect {

struct PartLandmarks {
  bool found = false;
  at::Tensor points;  // (K, 3) on the CPU: x, y (image pixels), z (pixels, relative)
  double score = 0;   // the landmark network's presence
  Region region;      // what it saw
};

enum class HandSide { kLeft, kRight };  // the subject's

class PartsLandmarker {
 public:
  explicit PartsLandmarker(at::Device device);
  // The subject's hand on `side`: none when the pose does not see its wrist.
  PartLandmarks hand(const at::Tensor& image, const PoseFrame& pose, HandSide side) const;
  // The 468 face-mesh points: none when no face is detected near the pose's face.
  PartLandmarks face(const at::Tensor& image, const PoseFrame& pose) const;

 private:
  TfliteNetwork recrop_, hand_, face_detector_, face_mesh_;
  at::Tensor face_anchors_;
};

}  // namespace sfgs::detect
