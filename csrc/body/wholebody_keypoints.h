#pragma once
// The 133 COCO-WholeBody keypoints (what DWPose / RTMPose whole-body detectors write) defined on an SMPL-X-layout
// body model, so `sfgs synth` projects them and `sfgs fit` fits to them by one definition. Order: 17 body (nose,
// eyes, ears, shoulders, elbows, wrists, hips, knees, ankles; left before right), 6 feet (big toe, small toe, heel;
// left, then right), 68 face (iBUG-68: jaw contour 0-16, brows, nose, eyes, mouth), 21 left hand and 21 right hand
// (OpenPose order: wrist, then thumb, index, middle, ring, pinky from knuckle to tip). docs/fitting.md has the table.
//
// Each keypoint is a joint of the model or a point on its surface (a vertex, or a barycentric point of a triangle):
// on the official SMPL-X mesh (10,475 vertices) the standard vertex ids of the SMPL-X reference loader (nose, eyes,
// ears, toes, heels, fingertips) and the model file's landmark embedding for the face; on any other mesh (the
// procedural body, the Anny stand-in) a geometric definition on the rest mesh (face_landmarks.h for the face).
#include <ATen/core/Tensor.h>

#include <array>
#include <cstdint>
#include <string>

#include "body/smplx.h"

namespace sfgs::body {

inline constexpr int64_t kWholeBodyKeypointCount = 133;
inline constexpr int64_t kFaceLandmarkCount = 68;     // iBUG-68
inline constexpr int64_t kFaceContourLandmarks = 17;  // iBUG points 0..16, the jaw contour
inline constexpr int64_t kStaticFaceLandmarks = 51;   // iBUG points 17..67 (SMPL-X's lmk_faces_idx)

enum class KeypointGroup { kBody, kFeet, kFace, kLeftHand, kRightHand };
inline constexpr std::array<KeypointGroup, 5> kKeypointGroups = {KeypointGroup::kBody, KeypointGroup::kFeet,
                                                                 KeypointGroup::kFace, KeypointGroup::kLeftHand,
                                                                 KeypointGroup::kRightHand};

struct KeypointRange {
  int64_t begin, end;  // [begin, end) in the 133
  int64_t size() const { return end - begin; }
};
KeypointRange keypoint_range(KeypointGroup group);
const char* keypoint_group_name(KeypointGroup group);  // "body", "feet", "face", "left_hand", "right_hand"

// "nose", "left_eye", ..., "face_0".."face_67", "left_hand_root", "left_thumb1".."left_pinky4", "right_...".
const std::array<std::string, kWholeBodyKeypointCount>& wholebody_keypoint_names();
// The keypoint each becomes when the body is mirrored left <-> right (the face, which has its own mirror
// symmetry, maps to itself): what a detector that confuses the sides reports.
const std::array<int64_t, kWholeBodyKeypointCount>& wholebody_mirrored_keypoints();

// SMPL-X's face landmark embedding (the official .npz keys lmk_faces_idx, lmk_bary_coords, dynamic_lmk_faces_idx,
// dynamic_lmk_bary_coords): triangles and barycentric coordinates of iBUG points 17..67, and of the jaw contour
// (points 0..16) per head-yaw bin, since the visible contour moves as the head turns.
struct LandmarkEmbedding {
  at::Tensor faces;                 // (51) int64 triangle per static landmark
  at::Tensor barycentrics;          // (51, 3) float64
  at::Tensor contour_faces;         // (bins, 17) int64
  at::Tensor contour_barycentrics;  // (bins, 17, 3) float64
  bool defined() const { return faces.defined(); }
};

// The embedding of an SMPL-X-layout .npz when it has one (undefined fields when it has none); shapes, index ranges
// against `face_count` triangles and barycentrics are checked, errors name the file and the key.
LandmarkEmbedding read_landmark_embedding(const std::string& npz_path, int64_t face_count);

// How each of the 133 keypoints is computed from a posed body: a joint, or up to three weighted surface vertices.
class WholeBodyKeypointMap {
 public:
  // `landmarks` may be undefined: the face is then placed geometrically (face_landmarks.h). The model's arrays are
  // read on the CPU once; the map is small and moves to any device with to().
  static WholeBodyKeypointMap build(const SmplxModelData& model, const LandmarkEmbedding& landmarks);

  // The model vertices every keypoint (and every contour bin) reads, sorted: a caller may pose only these.
  const at::Tensor& support_vertices() const { return support_vertices_; }
  int64_t contour_bin_count() const { return contour_vertex_slots_.size(0); }
  // "smplx-vertex-ids" (official mesh) or "geometric", and whether the face came from the model's embedding.
  const std::string& definition() const { return definition_; }
  bool face_from_embedding() const { return face_from_embedding_; }
  // (133) bool: true for points on the surface, false for joints (inside the body).
  at::Tensor on_surface() const;

  // (B, 133, 3) keypoints from posed support vertices (B, S, 3) (in support_vertices() order), posed joints
  // (B, 55, 3) and each frame's contour bin (B) int64 (contour_bins()). Differentiable, on the inputs' device.
  at::Tensor evaluate(const at::Tensor& support_positions, const at::Tensor& joints,
                      const at::Tensor& contour_bins) const;
  // The same from the whole posed mesh (B, V, 3).
  at::Tensor evaluate_on_mesh(const at::Tensor& vertices, const at::Tensor& joints,
                              const at::Tensor& contour_bins) const;

  // Its index tensors and weights on `device` in floating `dtype`.
  WholeBodyKeypointMap to(c10::Device device, at::ScalarType dtype) const;

 private:
  at::Tensor support_vertices_;        // (S) int64 model vertex ids
  at::Tensor joint_of_keypoint_;       // (133) int64 joint index, or 0 where joint_weight_ is 0
  at::Tensor joint_weight_;            // (133) 1 for joint keypoints, else 0
  at::Tensor vertex_slots_;            // (133, 3) int64 indices into the support vertices
  at::Tensor vertex_weights_;          // (133, 3) barycentric weights (zero for joint keypoints)
  at::Tensor contour_vertex_slots_;    // (bins, 17, 3) int64 support indices of the jaw contour per bin
  at::Tensor contour_vertex_weights_;  // (bins, 17, 3)
  std::string definition_;
  bool face_from_embedding_ = false;
};

// The map of a model read from the SMPL-X-layout .npz `model_path` (with the file's landmark embedding when it has
// one), or of the built-in procedural body when the path is empty (the face placed geometrically): what `sfgs synth`
// projects, `sfgs fit` fits to and pose fitting anchors on, by one definition.
WholeBodyKeypointMap wholebody_keypoint_map(const SmplxModelData& model, const std::string& model_path);

// The jaw-contour bin of each frame from the global rotation (B, 3, 3) of the neck joint in OpenCV camera
// coordinates, as the SMPL-X reference bins the neck chain's yaw (-39..39 degrees, 79 bins) for a camera that looks
// at the body's front: the contour follows the head's turn relative to the camera. (B) int64; zeros when the map
// has a single bin.
at::Tensor contour_bins(const at::Tensor& neck_rotation_in_camera, int64_t bin_count);

}  // namespace sfgs::body
