#include "body/parts.h"

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "io/npz.h"

namespace sfgs::body {
namespace {

at::Tensor checked_ids(const at::Tensor& ids, int64_t num_vertices, const std::string& what) {
  TORCH_CHECK(ids.dim() == 1 && at::isIntegralType(ids.scalar_type(), /*includeBool=*/false), what,
              " must be a 1-D integer array of vertex indices, got ", describe(ids));
  at::Tensor result = ids.to(at::kCPU, at::kLong).contiguous();
  if (result.numel() > 0) {
    const int64_t low = result.min().item<int64_t>(), high = result.max().item<int64_t>();
    TORCH_CHECK(low >= 0 && high < num_vertices, what, " holds vertex indices ", low, "..", high, ", but the body has ",
                num_vertices, " vertices (is it meant for another model?)");
  }
  return result;
}

}  // namespace

const char* body_part_name(BodyPart part) {
  switch (part) {
    case BodyPart::kBody:
      return "body";
    case BodyPart::kFace:
      return "face";
    case BodyPart::kLeftHand:
      return "left_hand";
    case BodyPart::kRightHand:
      return "right_hand";
  }
  return "unknown";
}

at::Tensor dominant_joints(const at::Tensor& weights) {
  TORCH_CHECK(weights.dim() == 2 && weights.size(1) > 0 && at::isFloatingType(weights.scalar_type()),
              "dominant_joints: weights must be floating with shape (V, J), got ", describe(weights));
  return weights.argmax(1);
}

at::Tensor part_labels_from_vertex_ids(int64_t num_vertices, const at::Tensor& face_ids,
                                       const at::Tensor& left_hand_ids, const at::Tensor& right_hand_ids) {
  at::Tensor labels = at::full({num_vertices}, static_cast<int64_t>(BodyPart::kBody), at::kByte);
  const auto assign = [&](const at::Tensor& ids, BodyPart part, const char* what) {
    if (ids.defined()) labels.index_fill_(0, checked_ids(ids, num_vertices, what), static_cast<int64_t>(part));
  };
  assign(face_ids, BodyPart::kFace, "face vertex ids");
  assign(left_hand_ids, BodyPart::kLeftHand, "left hand vertex ids");
  assign(right_hand_ids, BodyPart::kRightHand, "right hand vertex ids");
  return labels;
}

at::Tensor part_labels_from_weights(const at::Tensor& weights) {
  TORCH_CHECK(weights.dim() == 2 && weights.size(1) == kSmplxJointCount,
              "part_labels_from_weights: weights must have shape (V, ", kSmplxJointCount,
              ") in the SMPL-X joint order, got ", describe(weights));
  std::vector<uint8_t> part_of_joint(kSmplxJointCount, static_cast<uint8_t>(BodyPart::kBody));
  for (int64_t j : {smplx_joint::kHead, smplx_joint::kJaw, smplx_joint::kLeftEye, smplx_joint::kRightEye})
    part_of_joint[j] = static_cast<uint8_t>(BodyPart::kFace);
  for (int64_t k = 0; k < kManoJointCount; ++k) {
    part_of_joint[smplx_hand_joint(Side::kLeft, k)] = static_cast<uint8_t>(BodyPart::kLeftHand);
    part_of_joint[smplx_hand_joint(Side::kRight, k)] = static_cast<uint8_t>(BodyPart::kRightHand);
  }
  const at::Tensor table = at::tensor(std::vector<int64_t>(part_of_joint.begin(), part_of_joint.end()), at::kLong)
                               .to(weights.device(), at::kByte);
  return table.index_select(0, dominant_joints(weights));
}

HandVertexIds load_hand_vertex_ids(const std::string& npz_path, int64_t num_body_vertices) {
  const io::NpzArchive archive(npz_path);
  HandVertexIds ids;
  ids.left = checked_ids(archive.read("left_hand"), num_body_vertices, "'left_hand' of '" + npz_path + "'");
  ids.right = checked_ids(archive.read("right_hand"), num_body_vertices, "'right_hand' of '" + npz_path + "'");
  TORCH_CHECK(ids.left.size(0) == ids.right.size(0), "'", npz_path, "' gives the hands different vertex counts (",
              ids.left.size(0), " left, ", ids.right.size(0), " right)");
  return ids;
}

at::Tensor load_face_vertex_ids(const std::string& npy_path, int64_t num_body_vertices) {
  return checked_ids(io::read_npy(npy_path), num_body_vertices, "'" + npy_path + "'");
}

}  // namespace sfgs::body
