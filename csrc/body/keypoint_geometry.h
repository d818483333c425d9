#pragma once
// Where the surface keypoints of COCO-WholeBody lie on an SMPL-X-layout mesh (internal to wholebody_keypoints.cpp,
// exposed for its tests): the SMPL-X reference loader's vertex ids on the official mesh, and geometric definitions
// on the rest mesh of any other mesh (docs/fitting.md, "Keypoints on the body model").
#include <array>
#include <cstdint>

#include "body/smplx.h"
#include "body/wholebody_keypoints.h"

namespace sfgs::body {

// Fingers in COCO-WholeBody / OpenPose order.
inline constexpr int64_t kFingerCount = 5;  // thumb, index, middle, ring, pinky

struct SurfaceKeypointVertices {
  int64_t nose, left_eye, right_eye, left_ear, right_ear;
  std::array<int64_t, kFingerCount> left_fingertips, right_fingertips;
  int64_t left_big_toe, left_small_toe, left_heel, right_big_toe, right_small_toe, right_heel;
};

// The official SMPL-X mesh's vertex count, which selects the reference ids.
inline constexpr int64_t kOfficialSmplxVertexCount = 10475;

// The reference ids (smplx/vertex_ids.py, 'smplx') for the official mesh; otherwise, on the rest mesh:
// * fingertip: of the vertices dominated by the finger's last joint, the most distal along its last bone;
// * nose: the foremost (+z) head or jaw vertex between the eyes' height and 1.5 eye distances below it, within
//   half an eye distance of the midline;
// * eye: the foremost vertex dominated by that eye's joint (the eyeball's front), else the nearest head vertex in
//   front of the eye joint;
// * ear: the outermost head vertex within half an eye distance of the eyes' height;
// * big / small toe: the foremost vertex dominated by the foot (ball) joint on the inner / outer side of it;
// * heel: the rearmost vertex dominated by the ankle or foot joint below the ankle.
SurfaceKeypointVertices surface_keypoint_vertices(const SmplxModelData& model);

// A landmark embedding placed geometrically for a mesh without one: a mean iBUG-68 face layout, scaled by the
// distance between the eye joints and centred between them, is cast along -z onto the rest mesh's head (the
// foremost hit on a triangle skinned to the head or jaw). The contour has a single bin (it does not follow yaw).
LandmarkEmbedding place_face_landmarks(const SmplxModelData& model);

}  // namespace sfgs::body
