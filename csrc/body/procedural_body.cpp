// Assembly of the procedural body into the SMPL-X and MANO layouts: the smoothed cage and the eyes become one
// triangle mesh with weights, regressor, blend spaces and UVs; the hands are cut out of it. The pieces are built in
// csrc/body/procedural/.
#include "body/procedural_body.h"

#include <array>
#include <filesystem>
#include <stdexcept>
#include <tuple>
#include <vector>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/procedural/blend_spaces.h"
#include "body/procedural/body_cage.h"
#include "body/procedural/catmull_clark.h"
#include "body/procedural/eyes.h"
#include "body/procedural/uv_layout.h"
#include "body/skeleton.h"
#include "io/npz.h"

namespace sfgs::body {
namespace {

namespace J = smplx_joint;
using procedural::Chart;
using procedural::Smoothed;

struct Triangles {
  std::vector<int64_t> corners;  // three vertex indices per triangle
  std::vector<int64_t> charts;   // per triangle
};

// Each smoothed quad (vertex point, edge point, face point, edge point) is split between its two edge points, a
// choice that mirrors onto itself, so the triangulation stays symmetric. The eyes' vertices and charts are
// numbered after the body's.
Triangles triangulate(const Smoothed& body, const Smoothed& eyes, int64_t body_chart_count) {
  Triangles out;
  const int64_t body_count = body.positions.size(0);
  for (const auto& [mesh, vertex_offset, chart_offset] :
       {std::tuple{&body.quads, int64_t{0}, int64_t{0}}, {&eyes.quads, body_count, body_chart_count}}) {
    for (size_t q = 0; q < mesh->faces.size(); ++q) {
      const auto& c = mesh->faces[q];
      for (const auto& tri : {std::array<int64_t, 3>{c[0], c[1], c[3]}, {c[1], c[2], c[3]}}) {
        for (int64_t corner : tri) out.corners.push_back(corner + vertex_offset);
        out.charts.push_back(mesh->charts[q] + chart_offset);
      }
    }
  }
  return out;
}

// Catmull-Clark sums mirrored stencils in different orders; averaging each vertex with its mirror image makes the
// two halves agree to the last bit (IEEE addition commutes), so even ties in argmax-based labels stay symmetric.
void make_exactly_symmetric(SmplxModelData& d, const at::Tensor& mirror_index) {
  const at::Tensor joint_mirror =
      at::tensor(std::vector<int64_t>(kSmplxMirroredJoints.begin(), kSmplxMirroredJoints.end()), at::kLong);
  const at::Tensor flip_x = at::tensor(std::vector<double>{-1, 1, 1}, at::kDouble);
  d.v_template = 0.5 * (d.v_template + d.v_template.index_select(0, mirror_index) * flip_x);
  d.weights = 0.5 * (d.weights + d.weights.index_select(0, mirror_index).index_select(1, joint_mirror));
}

// Each joint is the mean of its vertex set; the eyes' sets are their eyeballs (the vertices from `first_eye_vertex`
// on, split by side).
at::Tensor joint_regressor(procedural::RegressorSets sets, const at::Tensor& v_template, int64_t first_eye_vertex) {
  const int64_t vertex_count = v_template.size(0);
  for (int64_t i = first_eye_vertex; i < vertex_count; ++i)
    sets[v_template[i][0].item<double>() > 0 ? J::kLeftEye : J::kRightEye].push_back(i);
  at::Tensor regressor = at::zeros({kSmplxJointCount, vertex_count}, at::kDouble);
  for (int64_t j = 0; j < kSmplxJointCount; ++j) {
    const auto& ids = sets[j];
    if (ids.empty()) throw std::logic_error("procedural body: no regressor for joint " + std::to_string(j));
    regressor[j].index_fill_(0, at::tensor(ids, at::kLong), 1.0 / static_cast<double>(ids.size()));
  }
  return regressor;
}

// The MANO-layout hand of `side`: the body's hand region (and the vertices its joints are regressed from) in the
// body's model space, open at the wrist, with MANO's 16 joints and the body shape space minus the wrist's motion.
ManoModelData cut_hand(const SmplxModelData& body, const at::Tensor& ids, const at::Tensor& faces, Side side,
                       const at::Tensor& components, const at::Tensor& mean) {
  std::vector<int64_t> hand_joints;
  for (int64_t k = 0; k < kManoJointCount; ++k) hand_joints.push_back(smplx_hand_joint(side, k));
  const at::Tensor joints = at::tensor(hand_joints, at::kLong);
  ManoModelData hand;
  hand.source = std::string("procedural ") + (side == Side::kLeft ? "left" : "right") + " hand";
  hand.v_template = body.v_template.index_select(0, ids);
  hand.faces = faces;
  hand.j_regressor = body.j_regressor.index_select(0, joints).index_select(1, ids);
  hand.weights = body.weights.index_select(0, ids).index_select(1, joints);
  hand.weights.select(1, 0).add_(1 - hand.weights.sum(1));  // the forearm's share moves with the wrist
  hand.parents.assign(kManoParents.begin(), kManoParents.end());
  const at::Tensor shape = body.shapedirs.narrow(2, 0, kManoShapeSpace);
  const at::Tensor wrist_motion = at::einsum("v,vck->ck", {body.j_regressor[hand_joints[0]], shape});
  hand.shapedirs = shape.index_select(0, ids) - wrist_motion.unsqueeze(0);
  hand.hands_components = components;
  hand.hands_mean = mean;
  return hand;
}

// The right hand region, then the left as its mirror image vertex by vertex.
void cut_mano_hands(ProceduralBody& out, const procedural::HandPoseSpace& hand_poses) {
  const SmplxModelData& d = out.smplx;
  at::Tensor in_hand = d.part_labels == static_cast<int64_t>(BodyPart::kRightHand);
  for (int64_t k = 0; k < kManoJointCount; ++k)
    in_hand = in_hand | (d.j_regressor[smplx_hand_joint(Side::kRight, k)] > 0);
  const at::Tensor right_ids = in_hand.nonzero().flatten();
  const at::Tensor left_ids = out.mirrored_vertices.index_select(0, right_ids);
  // Body faces with all three corners in the region, renumbered; the mirror image reverses their orientation.
  at::Tensor local = at::full({d.v_template.size(0)}, -1, at::kLong);
  local.index_copy_(0, right_ids, at::arange(right_ids.size(0), at::kLong));
  const at::Tensor corners = local.index_select(0, d.faces.flatten()).view({-1, 3});
  const at::Tensor right_faces = corners.index_select(0, (corners >= 0).all(1).nonzero().flatten());
  const at::Tensor left_faces = right_faces.flip(1).contiguous();
  out.hand_vertex_ids = {left_ids, right_ids};
  out.mano_right =
      cut_hand(d, right_ids, right_faces, Side::kRight, hand_poses.right_components, hand_poses.right_mean);
  out.mano_left = cut_hand(d, left_ids, left_faces, Side::kLeft, hand_poses.left_components, hand_poses.left_mean);
  out.mano_right.validate();
  out.mano_left.validate();
}

}  // namespace

SmplxModelData smplx_model_or_procedural(const std::string& path) {
  return path.empty() ? make_procedural_body().smplx : SmplxModelData::load(path);
}

ProceduralBody make_procedural_body() {
  const procedural::CageBuild build = procedural::build_cage();
  const Smoothed body = procedural::smooth(build.cage);
  std::vector<Chart> eye_charts;
  const Smoothed eyes = procedural::make_eyes(body.positions, eye_charts);
  const int64_t body_charts = static_cast<int64_t>(build.cage.charts().size());
  const Triangles triangles = triangulate(body, eyes, body_charts);
  std::vector<Chart> charts = build.cage.charts();
  charts.insert(charts.end(), eye_charts.begin(), eye_charts.end());

  ProceduralBody out;
  SmplxModelData& d = out.smplx;
  d.source = "procedural body";
  d.v_template = at::cat({body.positions, eyes.positions});
  d.faces = at::tensor(triangles.corners, at::kLong).view({-1, 3});
  std::vector<int64_t> mirror = body.mirror;
  for (int64_t m : eyes.mirror) mirror.push_back(m + body.positions.size(0));
  out.mirrored_vertices = at::tensor(mirror, at::kLong);
  d.weights = at::cat({body.weights, eyes.weights});
  make_exactly_symmetric(d, out.mirrored_vertices);
  d.j_regressor = joint_regressor(build.regressor, d.v_template, body.positions.size(0));
  d.parents.assign(kSmplxParents.begin(), kSmplxParents.end());
  const at::Tensor joints = d.j_regressor.matmul(d.v_template);
  d.shapedirs = procedural::shape_directions(d.v_template, d.weights, joints);
  d.exprdirs = procedural::expression_directions(d.v_template, d.weights, build);
  const procedural::HandPoseSpace hand_poses = procedural::hand_pose_space();
  d.hands_components_left = hand_poses.left_components;
  d.hands_components_right = hand_poses.right_components;
  d.hands_mean_left = hand_poses.left_mean;
  d.hands_mean_right = hand_poses.right_mean;
  const procedural::UvLayout uv_layout = procedural::make_uvs(d.v_template, d.faces, triangles.charts, charts);
  d.uvs = uv_layout.uvs;
  d.uv_faces = uv_layout.uv_faces;
  d.part_labels = part_labels_from_weights(d.weights);
  d.validate();
  out.mirrored_expressions.assign(procedural::kMirroredExpressions.begin(), procedural::kMirroredExpressions.end());
  out.face_vertex_ids = (d.part_labels == static_cast<int64_t>(BodyPart::kFace)).nonzero().flatten();
  cut_mano_hands(out, hand_poses);
  return out;
}

void write_procedural_body(const ProceduralBody& body, const std::string& folder, bool overwrite) {
  namespace fs = std::filesystem;
  TORCH_CHECK(fs::is_directory(folder), "write_procedural_body: folder '", folder, "' does not exist");
  const auto path = [&](const char* name) { return (fs::path(folder) / name).string(); };
  body.smplx.save(path("procedural_smplx.npz"), overwrite);
  body.mano_left.save(path("procedural_mano_left.npz"), overwrite);
  body.mano_right.save(path("procedural_mano_right.npz"), overwrite);
  io::write_npz(path("procedural_MANO_SMPLX_vertex_ids.npz"),
                {{"left_hand", body.hand_vertex_ids.left}, {"right_hand", body.hand_vertex_ids.right}}, overwrite);
  io::write_npy(path("procedural_face_vertex_ids.npy"), body.face_vertex_ids, overwrite);
}

}  // namespace sfgs::body
