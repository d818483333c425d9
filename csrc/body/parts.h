#pragma once
// Body-part labels (body, face, left hand, right hand) and the files that define the regions on SMPL-X:
// MANO_SMPLX_vertex_ids (converted to .npz) for the hands and SMPL-X__FLAME_vertex_ids.npy for the face.
#include <cstdint>
#include <string>

#include <ATen/core/Tensor.h>

namespace sfgs::body {

// Stored as uint8 per vertex. The order matters: subdividing labels keeps the larger one (see mesh.h).
enum class BodyPart : uint8_t { kBody = 0, kFace = 1, kLeftHand = 2, kRightHand = 3 };
inline constexpr int64_t kBodyPartCount = 4;
const char* body_part_name(BodyPart part);

// The joint with the largest skinning weight per vertex, (V, J) -> (V) int64 (SFGS binds each Gaussian to it).
at::Tensor dominant_joints(const at::Tensor& weights);

// Labels from vertex-id sets (any of them may be undefined): face first, then hands, so hands win an overlap.
at::Tensor part_labels_from_vertex_ids(int64_t num_vertices, const at::Tensor& face_ids,
                                       const at::Tensor& left_hand_ids, const at::Tensor& right_hand_ids);

// Labels from SMPL-X skinning weights (V, 55) when no id files are at hand: a vertex dominated by the head, jaw or
// an eye is face, one dominated by a wrist or finger joint is that hand.
at::Tensor part_labels_from_weights(const at::Tensor& weights);

// Body-vertex index of every MANO-layout vertex of each hand, (Vh) int64, checked against the body's vertex count.
struct HandVertexIds {
  at::Tensor left;
  at::Tensor right;
};
HandVertexIds load_hand_vertex_ids(const std::string& npz_path, int64_t num_body_vertices);

// The body vertices of the face region, (N) int64, from an integer .npy such as SMPL-X__FLAME_vertex_ids.npy.
at::Tensor load_face_vertex_ids(const std::string& npy_path, int64_t num_body_vertices);

}  // namespace sfgs::body
