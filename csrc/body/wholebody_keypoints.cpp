#include "body/wholebody_keypoints.h"

#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <vector>

#include "body/keypoint_geometry.h"
#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "body/constants.h"
#include "io/npz.h"

namespace sfgs::body {
namespace {

constexpr int64_t kFeetBegin = 17, kFaceBegin = 23, kLeftHandBegin = 91, kRightHandBegin = 112;
constexpr int64_t kHandKeypoints = 21;
constexpr int64_t kStaticFaceBegin = kFaceBegin + kFaceContourLandmarks;

// One keypoint's recipe: a joint, or up to three weighted model vertices.
struct Recipe {
  int64_t joint = -1;
  std::array<int64_t, 3> vertices{0, 0, 0};
  std::array<double, 3> weights{0, 0, 0};
};

Recipe joint_recipe(int64_t joint) { return Recipe{joint, {0, 0, 0}, {0, 0, 0}}; }
Recipe vertex_recipe(int64_t vertex) { return Recipe{-1, {vertex, vertex, vertex}, {1, 0, 0}}; }

Recipe triangle_recipe(const at::Tensor& faces, int64_t face, const at::Tensor& barycentric) {
  Recipe r;
  for (int64_t k = 0; k < 3; ++k) {
    r.vertices[size_t(k)] = faces[face][k].item<int64_t>();
    r.weights[size_t(k)] = barycentric[k].item<double>();
  }
  return r;
}

void check_embedding_array(const at::Tensor& t, std::vector<int64_t> shape, const std::string& where) {
  TORCH_CHECK(t.dim() == int64_t(shape.size()), where, " must have ", shape.size(), " dimensions, got ", describe(t));
  for (size_t d = 0; d < shape.size(); ++d)
    TORCH_CHECK(shape[d] < 0 || t.size(int64_t(d)) == shape[d], where, " has shape ", t.sizes(), ", expected ",
                at::IntArrayRef(shape), " (-1: any)");
}

}  // namespace

KeypointRange keypoint_range(KeypointGroup group) {
  switch (group) {
    case KeypointGroup::kBody:
      return {0, kFeetBegin};
    case KeypointGroup::kFeet:
      return {kFeetBegin, kFaceBegin};
    case KeypointGroup::kFace:
      return {kFaceBegin, kLeftHandBegin};
    case KeypointGroup::kLeftHand:
      return {kLeftHandBegin, kRightHandBegin};
    case KeypointGroup::kRightHand:
      return {kRightHandBegin, kWholeBodyKeypointCount};
  }
  return {0, 0};
}

const char* keypoint_group_name(KeypointGroup group) {
  switch (group) {
    case KeypointGroup::kBody:
      return "body";
    case KeypointGroup::kFeet:
      return "feet";
    case KeypointGroup::kFace:
      return "face";
    case KeypointGroup::kLeftHand:
      return "left_hand";
    case KeypointGroup::kRightHand:
      return "right_hand";
  }
  return "unknown";
}

const std::array<std::string, kWholeBodyKeypointCount>& wholebody_keypoint_names() {
  static const std::array<std::string, kWholeBodyKeypointCount> names = [] {
    std::array<std::string, kWholeBodyKeypointCount> n;
    const char* body[kFaceBegin] = {"nose",          "left_eye",        "right_eye",    "left_ear",       "right_ear",
                                    "left_shoulder", "right_shoulder",  "left_elbow",   "right_elbow",    "left_wrist",
                                    "right_wrist",   "left_hip",        "right_hip",    "left_knee",      "right_knee",
                                    "left_ankle",    "right_ankle",     "left_big_toe", "left_small_toe", "left_heel",
                                    "right_big_toe", "right_small_toe", "right_heel"};
    for (int64_t i = 0; i < kFaceBegin; ++i) n[size_t(i)] = body[i];
    for (int64_t i = 0; i < kFaceLandmarkCount; ++i) n[size_t(kFaceBegin + i)] = "face_" + std::to_string(i);
    const char* fingers[kFingerCount] = {"thumb", "index", "middle", "ring", "pinky"};
    for (const char* side : {"left", "right"}) {
      const int64_t begin = std::string(side) == "left" ? kLeftHandBegin : kRightHandBegin;
      n[size_t(begin)] = std::string(side) + "_hand_root";
      for (int64_t f = 0; f < kFingerCount; ++f)
        for (int64_t k = 0; k < 4; ++k)
          n[size_t(begin + 1 + 4 * f + k)] = std::string(side) + "_" + fingers[f] + std::to_string(k + 1);
    }
    return n;
  }();
  return names;
}

const std::array<int64_t, kWholeBodyKeypointCount>& wholebody_mirrored_keypoints() {
  static const std::array<int64_t, kWholeBodyKeypointCount> mirror = [] {
    std::array<int64_t, kWholeBodyKeypointCount> m{};
    for (int64_t i = 0; i < kWholeBodyKeypointCount; ++i) m[size_t(i)] = i;
    for (int64_t i = 1; i < kFeetBegin; i += 2) {  // eyes, ears, shoulders, ... ankles come in left/right pairs
      m[size_t(i)] = i + 1;
      m[size_t(i + 1)] = i;
    }
    for (int64_t i = 0; i < 3; ++i) {
      m[size_t(kFeetBegin + i)] = kFeetBegin + 3 + i;
      m[size_t(kFeetBegin + 3 + i)] = kFeetBegin + i;
    }
    for (int64_t i = 0; i < kHandKeypoints; ++i) {
      m[size_t(kLeftHandBegin + i)] = kRightHandBegin + i;
      m[size_t(kRightHandBegin + i)] = kLeftHandBegin + i;
    }
    return m;
  }();
  return mirror;
}

LandmarkEmbedding read_landmark_embedding(const std::string& npz_path, int64_t face_count) {
  const io::NpzArchive npz(npz_path);
  LandmarkEmbedding e;
  if (!npz.contains("lmk_faces_idx")) return e;
  for (const char* key : {"lmk_bary_coords", "dynamic_lmk_faces_idx", "dynamic_lmk_bary_coords"})
    TORCH_CHECK(npz.contains(key), "'", npz_path, "' has 'lmk_faces_idx' but lacks '", key,
                "' (SMPL-X's landmark embedding comes as four arrays)");
  const auto where = [&](const char* key) { return "'" + std::string(key) + "' of '" + npz_path + "'"; };
  e.faces = npz.read("lmk_faces_idx").to(at::kLong);
  e.barycentrics = npz.read("lmk_bary_coords").to(at::kDouble);
  e.contour_faces = npz.read("dynamic_lmk_faces_idx").to(at::kLong);
  e.contour_barycentrics = npz.read("dynamic_lmk_bary_coords").to(at::kDouble);
  check_embedding_array(e.faces, {kStaticFaceLandmarks}, where("lmk_faces_idx"));
  check_embedding_array(e.barycentrics, {kStaticFaceLandmarks, 3}, where("lmk_bary_coords"));
  check_embedding_array(e.contour_faces, {-1, kFaceContourLandmarks}, where("dynamic_lmk_faces_idx"));
  check_embedding_array(e.contour_barycentrics, {e.contour_faces.size(0), kFaceContourLandmarks, 3},
                        where("dynamic_lmk_bary_coords"));
  TORCH_CHECK(e.contour_faces.size(0) >= 1, where("dynamic_lmk_faces_idx"), " has no yaw bin");
  for (const auto& [faces, key] :
       {std::make_pair(e.faces, "lmk_faces_idx"), std::make_pair(e.contour_faces, "dynamic_lmk_faces_idx")})
    TORCH_CHECK(faces.min().item<int64_t>() >= 0 && faces.max().item<int64_t>() < face_count, where(key),
                " indexes triangles outside [0, ", face_count, ")");
  for (const auto& [bary, key] : {std::make_pair(e.barycentrics, "lmk_bary_coords"),
                                  std::make_pair(e.contour_barycentrics, "dynamic_lmk_bary_coords")})
    TORCH_CHECK(
        bary.isfinite().all().item<bool>() && (bary.sum(-1) - 1).abs().max().item<double>() < kBarycentricSumTolerance,
        where(key), " must hold finite barycentric coordinates summing to 1");
  return e;
}

WholeBodyKeypointMap WholeBodyKeypointMap::build(const SmplxModelData& model, const LandmarkEmbedding& landmarks) {
  using namespace smplx_joint;
  const SurfaceKeypointVertices s = surface_keypoint_vertices(model);
  const LandmarkEmbedding face = landmarks.defined() ? landmarks : place_face_landmarks(model);
  const at::Tensor faces = model.faces.to(at::kCPU, at::kLong);

  std::vector<Recipe> recipes(static_cast<size_t>(kWholeBodyKeypointCount));
  const int64_t body_vertices[5] = {s.nose, s.left_eye, s.right_eye, s.left_ear, s.right_ear};
  for (int64_t i = 0; i < 5; ++i) recipes[size_t(i)] = vertex_recipe(body_vertices[i]);
  const int64_t body_joints[12] = {kLeftShoulder, kRightShoulder, kLeftElbow, kRightElbow, kLeftWrist, kRightWrist,
                                   kLeftHip,      kRightHip,      kLeftKnee,  kRightKnee,  kLeftAnkle, kRightAnkle};
  for (int64_t i = 0; i < 12; ++i) recipes[size_t(5 + i)] = joint_recipe(body_joints[i]);
  const int64_t feet[6] = {s.left_big_toe,  s.left_small_toe,  s.left_heel,
                           s.right_big_toe, s.right_small_toe, s.right_heel};
  for (int64_t i = 0; i < 6; ++i) recipes[size_t(kFeetBegin + i)] = vertex_recipe(feet[i]);
  for (int64_t i = 0; i < kStaticFaceLandmarks; ++i)
    recipes[size_t(kStaticFaceBegin + i)] = triangle_recipe(faces, face.faces[i].item<int64_t>(), face.barycentrics[i]);
  // Hands: the wrist, then per finger (OpenPose order) its three joints and the tip.
  const int64_t smplx_finger_slot[kFingerCount] = {4, 0, 1, 3, 2};
  for (Side side : {Side::kLeft, Side::kRight}) {
    const int64_t begin = side == Side::kLeft ? kLeftHandBegin : kRightHandBegin;
    const int64_t first = side == Side::kLeft ? kLeftHandFirst : kRightHandFirst;
    const auto& tips = side == Side::kLeft ? s.left_fingertips : s.right_fingertips;
    recipes[size_t(begin)] = joint_recipe(side == Side::kLeft ? kLeftWrist : kRightWrist);
    for (int64_t f = 0; f < kFingerCount; ++f) {
      for (int64_t k = 0; k < 3; ++k)
        recipes[size_t(begin + 1 + 4 * f + k)] = joint_recipe(first + 3 * smplx_finger_slot[f] + k);
      recipes[size_t(begin + 4 + 4 * f)] = vertex_recipe(tips[size_t(f)]);
    }
  }

  // The support: every vertex a recipe or a contour bin reads, sorted; recipes then address it by slot.
  const at::Tensor contour_vertices = faces.index_select(0, face.contour_faces.flatten());  // (bins * 17, 3)
  std::vector<int64_t> used(contour_vertices.data_ptr<int64_t>(),
                            contour_vertices.data_ptr<int64_t>() + contour_vertices.numel());
  for (const Recipe& r : recipes)
    if (r.joint < 0) used.insert(used.end(), r.vertices.begin(), r.vertices.end());
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  std::map<int64_t, int64_t> slot_of;
  for (size_t i = 0; i < used.size(); ++i) slot_of[used[i]] = int64_t(i);

  WholeBodyKeypointMap m;
  m.support_vertices_ = at::tensor(used, at::kLong);
  m.joint_of_keypoint_ = at::zeros({kWholeBodyKeypointCount}, at::kLong);
  m.joint_weight_ = at::zeros({kWholeBodyKeypointCount}, at::kDouble);
  m.vertex_slots_ = at::zeros({kWholeBodyKeypointCount, 3}, at::kLong);
  m.vertex_weights_ = at::zeros({kWholeBodyKeypointCount, 3}, at::kDouble);
  for (int64_t i = 0; i < kWholeBodyKeypointCount; ++i) {
    const Recipe& r = recipes[size_t(i)];
    if (r.joint >= 0) {
      m.joint_of_keypoint_[i] = r.joint;
      m.joint_weight_[i] = 1.0;
      continue;
    }
    const bool contour = i >= kFaceBegin && i < kStaticFaceBegin;  // read per bin in evaluate()
    for (int64_t k = 0; k < 3 && !contour; ++k) {
      m.vertex_slots_[i][k] = slot_of.at(r.vertices[size_t(k)]);
      m.vertex_weights_[i][k] = r.weights[size_t(k)];
    }
  }
  std::vector<int64_t> contour_slots;
  for (int64_t i = 0; i < contour_vertices.numel(); ++i)
    contour_slots.push_back(slot_of.at(contour_vertices.data_ptr<int64_t>()[i]));
  const int64_t bins = face.contour_faces.size(0);
  m.contour_vertex_slots_ = at::tensor(contour_slots, at::kLong).view({bins, kFaceContourLandmarks, 3});
  m.contour_vertex_weights_ = face.contour_barycentrics.to(at::kDouble).contiguous();
  m.definition_ = model.v_template.size(0) == kOfficialSmplxVertexCount ? "smplx-vertex-ids" : "geometric";
  m.face_from_embedding_ = landmarks.defined();
  return m;
}

WholeBodyKeypointMap wholebody_keypoint_map(const SmplxModelData& model, const std::string& model_path) {
  return WholeBodyKeypointMap::build(
      model, model_path.empty() ? LandmarkEmbedding{} : read_landmark_embedding(model_path, model.faces.size(0)));
}

at::Tensor WholeBodyKeypointMap::on_surface() const { return joint_weight_ == 0; }

WholeBodyKeypointMap WholeBodyKeypointMap::to(c10::Device device, at::ScalarType dtype) const {
  WholeBodyKeypointMap m = *this;
  for (at::Tensor* t : {&m.support_vertices_, &m.joint_of_keypoint_, &m.vertex_slots_, &m.contour_vertex_slots_})
    *t = t->to(device);
  for (at::Tensor* t : {&m.joint_weight_, &m.vertex_weights_, &m.contour_vertex_weights_}) *t = t->to(device, dtype);
  return m;
}

at::Tensor WholeBodyKeypointMap::evaluate(const at::Tensor& support_positions, const at::Tensor& joints,
                                          const at::Tensor& contour_bins) const {
  TORCH_CHECK(support_positions.dim() == 3 && support_positions.size(1) == support_vertices_.size(0) &&
                  support_positions.size(2) == 3,
              "WholeBodyKeypointMap::evaluate: support positions must be (B, ", support_vertices_.size(0), ", 3), got ",
              describe(support_positions));
  const int64_t batch = support_positions.size(0);
  TORCH_CHECK(joints.dim() == 3 && joints.size(0) == batch && joints.size(1) == kSmplxJointCount && joints.size(2) == 3,
              "WholeBodyKeypointMap::evaluate: joints must be (", batch, ", ", kSmplxJointCount, ", 3), got ",
              describe(joints));
  TORCH_CHECK(contour_bins.dim() == 1 && contour_bins.size(0) == batch,
              "WholeBodyKeypointMap::evaluate: contour bins must be (", batch, "), got ", describe(contour_bins));
  const auto device = support_positions.device();
  const auto floating = support_positions.options();
  const at::Tensor from_joints =
      joints.index_select(1, joint_of_keypoint_.to(device)) * joint_weight_.to(floating).view({1, -1, 1});
  const at::Tensor corners = support_positions.index_select(1, vertex_slots_.to(device).flatten())
                                 .view({batch, kWholeBodyKeypointCount, 3, 3});
  const at::Tensor keypoints = from_joints + (corners * vertex_weights_.to(floating).view({1, -1, 3, 1})).sum(2);

  const at::Tensor bins = contour_bins.to(device, at::kLong);
  const at::Tensor slots = contour_vertex_slots_.to(device).index_select(0, bins);  // (B, 17, 3)
  const at::Tensor contour_corners = support_positions.gather(1, slots.view({batch, -1, 1}).expand({-1, -1, 3}))
                                         .view({batch, kFaceContourLandmarks, 3, 3});
  const at::Tensor contour_weights = contour_vertex_weights_.to(floating).index_select(0, bins).unsqueeze(-1);
  const at::Tensor contour = (contour_corners * contour_weights).sum(2);
  return at::cat({keypoints.narrow(1, 0, kFaceBegin), contour,
                  keypoints.narrow(1, kStaticFaceBegin, kWholeBodyKeypointCount - kStaticFaceBegin)},
                 1);
}

at::Tensor WholeBodyKeypointMap::evaluate_on_mesh(const at::Tensor& vertices, const at::Tensor& joints,
                                                  const at::Tensor& contour_bins) const {
  TORCH_CHECK(
      vertices.dim() == 3 && vertices.size(2) == 3 && vertices.size(1) > support_vertices_.max().item<int64_t>(),
      "WholeBodyKeypointMap::evaluate_on_mesh: vertices must be (B, V, 3) of the model the map was built "
      "for, got ",
      describe(vertices));
  return evaluate(vertices.index_select(1, support_vertices_.to(vertices.device())), joints, contour_bins);
}

at::Tensor contour_bins(const at::Tensor& neck_rotation_in_camera, int64_t bin_count) {
  TORCH_CHECK(neck_rotation_in_camera.dim() == 3 && neck_rotation_in_camera.size(1) == 3 &&
                  neck_rotation_in_camera.size(2) == 3,
              "contour_bins: expected (B, 3, 3) rotations, got ", describe(neck_rotation_in_camera));
  const int64_t batch = neck_rotation_in_camera.size(0);
  const auto options = neck_rotation_in_camera.options().dtype(at::kLong);
  if (bin_count <= 1) return at::zeros({batch}, options);
  // The camera looks at the body's front from +z with y up: undo OpenCV's y-down, z-forward axes (diag(1, -1, -1)).
  const at::Tensor r = neck_rotation_in_camera.detach();
  const at::Tensor r00 = r.select(1, 0).select(1, 0), r10 = -r.select(1, 1).select(1, 0);
  const at::Tensor r20 = -r.select(1, 2).select(1, 0);
  const at::Tensor yaw = -at::atan2(-r20, at::sqrt(r00 * r00 + r10 * r10));
  const int64_t half = (bin_count - 1) / 2;
  const at::Tensor degrees = at::round(at::clamp_max(yaw * (180.0 / M_PI), double(half))).to(at::kLong);
  // The reference's layout: bins 0..half for turns of 0..half degrees one way, half+1..2 half the other way.
  const at::Tensor negative = (half - degrees).clamp_max(2 * half);
  return at::where(degrees < 0, negative, degrees).to(options);
}

}  // namespace sfgs::body
