#include "detect/parts.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <ATen/ATen.h>

#include "common/math_constants.h"
#include "detect/models.h"

namespace sfgs::detect {
namespace {

// Hands: the pose's wrist, pinky and index landmarks of each side; a hand is looked for where its wrist is visible.
constexpr int kWrist[2] = {15, 16}, kPinky[2] = {17, 18}, kIndex[2] = {19, 20};
constexpr double kMinWristVisibility = 0.1;
// The region from the pose: centred between index and pinky, turned upright from the wrist, 2.7 times twice the
// wrist's distance, shifted 0.1 towards the wrist.
constexpr double kHandFromPoseScale = 2.7, kHandShift = -0.1;
// The re-crop network (256 x 256) gives two points that align the hand's region (pointing up, -90 degrees).
constexpr int64_t kRecropSize = 256;
// The hand landmark network: 224 x 224; 21 points of 3 values; a presence above 0.5 is a hand.
constexpr int64_t kHandSize = 224, kHandPoints = 21;
constexpr double kMinPresence = 0.5;
// The face: the pose's face points (nose, eyes, ears, mouth: 0-10), turned level from its right eye (5) to its left
// (2), three times as large; the detector (128 x 128, six keypoints) inside it; the mesh network (192 x 192, 468
// points) on the detection's keypoints' box turned level from its right eye (0) to its left (1), twice as large.
constexpr int kPoseFacePoints = 11, kPoseRightEye = 5, kPoseLeftEye = 2;
constexpr double kFaceFromPoseScale = 3.0;
const SsdLayout kFaceDetectorLayout{128, {8, 16}, {2, 6}, 6};
constexpr double kMinFaceScore = 0.5;
constexpr int kDetectionRightEye = 0, kDetectionLeftEye = 1;
constexpr double kFaceScale = 2.0, kFaceShift = -0.1;
constexpr int64_t kMeshSize = 192, kMeshPoints = 468;

std::array<double, 2> point(const at::Tensor& landmarks, int64_t k) {
  return {landmarks[k][0].item<double>(), landmarks[k][1].item<double>()};
}

double rotation_of(const std::array<double, 2>& a, const std::array<double, 2>& b, double target) {
  return alignment_rotation(a[0], a[1], b[0], b[1], target);
}

// The axis-aligned box of `points` (image pixels), turned by `rotation` about its centre.
Region box_region(const std::vector<std::array<double, 2>>& points, double rotation) {
  double x0 = std::numeric_limits<double>::infinity(), y0 = x0, x1 = -x0, y1 = -x0;
  for (const auto& p : points) {
    x0 = std::min(x0, p[0]);
    x1 = std::max(x1, p[0]);
    y0 = std::min(y0, p[1]);
    y1 = std::max(y1, p[1]);
  }
  Region r;
  r.cx = 0.5 * (x0 + x1);
  r.cy = 0.5 * (y0 + y1);
  r.width = x1 - x0;
  r.height = y1 - y0;
  r.rotation = rotation;
  return r;
}

// Points (K, 3) in a region's crop of `size` pixels as image points: x, y through the region, z scaled like x.
at::Tensor crop_points_to_image(const at::Tensor& crop_points, const Region& region, int64_t size) {
  const at::Tensor p = crop_points.to(at::kCPU, at::kDouble);
  const at::Tensor xy = points_to_image(p.slice(1, 0, 2) / double(size), region);
  return at::cat({xy, p.slice(1, 2, 3) / double(size) * region.width}, 1).to(at::kFloat);
}

}  // namespace

PartsLandmarker::PartsLandmarker(at::Device device)
    : recrop_(TfliteNetwork::load(mediapipe_model("hand_recrop.tflite"), device)),
      hand_(TfliteNetwork::load(mediapipe_model("hand_landmark_full.tflite"), device)),
      face_detector_(TfliteNetwork::load(mediapipe_model("face_detection_short_range.tflite"), device)),
      face_mesh_(TfliteNetwork::load(mediapipe_model("face_landmark.tflite"), device)),
      face_anchors_(ssd_anchors(kFaceDetectorLayout)) {}

PartLandmarks PartsLandmarker::hand(const at::Tensor& image, const PoseFrame& pose, HandSide side) const {
  PartLandmarks out;
  const int s = side == HandSide::kLeft ? 0 : 1;
  if (!pose.found || pose.landmarks[kWrist[s]][3].item<double>() <= kMinWristVisibility) return out;
  const auto wrist = point(pose.landmarks, kWrist[s]), pinky = point(pose.landmarks, kPinky[s]),
             index = point(pose.landmarks, kIndex[s]);
  const std::array<double, 2> middle = {(2 * index[0] + pinky[0]) / 3, (2 * index[1] + pinky[1]) / 3};
  Region from_pose;
  from_pose.cx = middle[0];
  from_pose.cy = middle[1];
  from_pose.width = from_pose.height = 2 * std::hypot(middle[0] - wrist[0], middle[1] - wrist[1]);
  from_pose.rotation = rotation_of(wrist, middle, kPi / 2);
  from_pose = from_pose.shifted(0, kHandShift).scaled(kHandFromPoseScale, true);
  // The re-crop network's two points align the region on the hand itself.
  const at::Tensor two = recrop_.run({crop(image, from_pose, kRecropSize, 0.0, 1.0, Border::kReplicate)})[0];
  const at::Tensor aligned =
      points_to_image(two.reshape({2, 2}).to(at::kCPU, at::kDouble) / double(kRecropSize), from_pose);
  const std::array<double, 2> a = {aligned[0][0].item<double>(), aligned[0][1].item<double>()},
                              b = {aligned[1][0].item<double>(), aligned[1][1].item<double>()};
  out.region = alignment_region(a[0], a[1], b[0], b[1], -kPi / 2).shifted(0, kHandShift).scaled(1.0, true);
  const std::vector<at::Tensor> result = hand_.run({crop(image, out.region, kHandSize, 0.0, 1.0, Border::kReplicate)});
  out.score = result[1].item<double>();
  if (!(out.score > kMinPresence)) return out;
  out.found = true;
  out.points = crop_points_to_image(result[0].reshape({kHandPoints, 3}), out.region, kHandSize);
  return out;
}

PartLandmarks PartsLandmarker::face(const at::Tensor& image, const PoseFrame& pose) const {
  PartLandmarks out;
  if (!pose.found) return out;
  std::vector<std::array<double, 2>> face_points;
  for (int k = 0; k < kPoseFacePoints; ++k) face_points.push_back(point(pose.landmarks, k));
  const Region around =
      box_region(face_points, rotation_of(point(pose.landmarks, kPoseRightEye), point(pose.landmarks, kPoseLeftEye), 0))
          .scaled(kFaceFromPoseScale, true);
  const std::vector<at::Tensor> detected =
      face_detector_.run({crop(image, around, kFaceDetectorLayout.input, -1.0, 1.0, Border::kZero)});
  const std::vector<std::vector<double>> faces =
      detections(detected[0], detected[1], face_anchors_, kFaceDetectorLayout, kMinFaceScore);
  if (faces.empty()) return out;
  const std::vector<double>& best = faces.front();
  std::vector<std::array<double, 2>> keypoints;
  for (int64_t k = 0; k < kFaceDetectorLayout.keypoints; ++k)
    keypoints.push_back(around.to_image(best[size_t(4 + 2 * k)], best[size_t(5 + 2 * k)]));
  out.region = box_region(keypoints, rotation_of(keypoints[kDetectionRightEye], keypoints[kDetectionLeftEye], 0))
                   .shifted(0, kFaceShift)
                   .scaled(kFaceScale, true);
  const std::vector<at::Tensor> mesh =
      face_mesh_.run({crop(image, out.region, kMeshSize, 0.0, 1.0, Border::kReplicate)});
  out.score = at::sigmoid(mesh[1].reshape({})).item<double>();
  if (!(out.score > kMinPresence)) return out;
  out.found = true;
  out.points = crop_points_to_image(mesh[0].reshape({kMeshPoints, 3}), out.region, kMeshSize);
  return out;
}

}  // namespace sfgs::detect
