#pragma once
// The SMPL-X and MANO joint layouts: joint counts, names, kinematic trees and the left/right correspondence.
#include <array>
#include <cstdint>

namespace sfgs::body {

inline constexpr int64_t kSmplxJointCount = 55;
inline constexpr int64_t kSmplxBodyJointCount = 21;  // body_pose covers joints 1..21
inline constexpr int64_t kHandJointCount = 15;       // per hand: index, middle, pinky, ring, thumb; 3 joints each
inline constexpr int64_t kHandPoseSize = 3 * kHandJointCount;
inline constexpr int64_t kManoJointCount = 1 + kHandJointCount;  // wrist, then the hand joints in SMPL-X order
// SMPL-X v1.1 splits its 400 blend-shape columns into 300 shape and 100 expression directions; v1.0 into 10 + 10.
inline constexpr int64_t kSmplxShapeSpace = 300;
inline constexpr int64_t kSmplxExpressionSpace = 100;
inline constexpr int64_t kSmplxV10ShapeSpace = 10;
inline constexpr int64_t kSmplxV10ExpressionSpace = 10;
inline constexpr int64_t kManoShapeSpace = 10;

// The joint tables keep their lines: names and indices in the layouts' order, several a line.
// clang-format off
namespace smplx_joint {
enum : int64_t {
  kPelvis = 0, kLeftHip, kRightHip, kSpine1, kLeftKnee, kRightKnee, kSpine2, kLeftAnkle, kRightAnkle, kSpine3,
  kLeftFoot, kRightFoot, kNeck, kLeftCollar, kRightCollar, kHead, kLeftShoulder, kRightShoulder, kLeftElbow,
  kRightElbow, kLeftWrist, kRightWrist, kJaw, kLeftEye, kRightEye,
  kLeftHandFirst = 25,   // left_index1; the left hand's 15 joints are 25..39
  kRightHandFirst = 40,  // right_index1; the right hand's 15 joints are 40..54
};
}  // namespace smplx_joint

inline constexpr std::array<const char*, kSmplxJointCount> kSmplxJointNames = {
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw",
    "left_eye_smplhf", "right_eye_smplhf",
    "left_index1", "left_index2", "left_index3", "left_middle1", "left_middle2", "left_middle3",
    "left_pinky1", "left_pinky2", "left_pinky3", "left_ring1", "left_ring2", "left_ring3",
    "left_thumb1", "left_thumb2", "left_thumb3",
    "right_index1", "right_index2", "right_index3", "right_middle1", "right_middle2", "right_middle3",
    "right_pinky1", "right_pinky2", "right_pinky3", "right_ring1", "right_ring2", "right_ring3",
    "right_thumb1", "right_thumb2", "right_thumb3"};

inline constexpr std::array<int64_t, kSmplxJointCount> kSmplxParents = {
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53};

// The joint each joint becomes when the body is mirrored through the x = 0 plane (left <-> right).
inline constexpr std::array<int64_t, kSmplxJointCount> kSmplxMirroredJoints = {
    0, 2, 1, 3, 5, 4, 6, 8, 7, 9, 11, 10, 12, 14, 13, 15, 17, 16, 19, 18, 21, 20, 22, 24, 23,
    40, 41, 42, 43, 44, 45, 46, 47, 48, 49, 50, 51, 52, 53, 54,
    25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 37, 38, 39};

inline constexpr std::array<const char*, kManoJointCount> kManoJointNames = {
    "wrist", "index1", "index2", "index3", "middle1", "middle2", "middle3", "pinky1", "pinky2", "pinky3",
    "ring1", "ring2", "ring3", "thumb1", "thumb2", "thumb3"};

inline constexpr std::array<int64_t, kManoJointCount> kManoParents = {-1, 0, 1, 2, 0, 4, 5, 0, 7, 8,
                                                                     0, 10, 11, 0, 13, 14};

// clang-format on
enum class Side { kLeft, kRight };

// MANO joint k of a hand is SMPL-X joint smplx_hand_joint(side, k): the wrist, then the 15 finger joints.
inline int64_t smplx_hand_joint(Side side, int64_t mano_joint) {
  if (mano_joint == 0) return side == Side::kLeft ? smplx_joint::kLeftWrist : smplx_joint::kRightWrist;
  return (side == Side::kLeft ? smplx_joint::kLeftHandFirst : smplx_joint::kRightHandFirst) + mano_joint - 1;
}

}  // namespace sfgs::body
