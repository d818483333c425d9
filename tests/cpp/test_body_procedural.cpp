// The built-in procedural body (csrc/body/procedural_body.h): SMPL-X layout, a closed outward surface, exact
// left/right symmetry of everything, separate fingers, a jaw that opens the mouth, eyes, smooth weights, shape and
// expression directions, UVs, and its MANO-layout hands.
#include <cmath>
#include <map>
#include <set>

#include <gtest/gtest.h>

#include "body/mesh.h"
#include "body/parts.h"
#include "body/procedural/catmull_clark.h"
#include "body/procedural/poly_mesh.h"
#include "body/skeleton.h"
#include "body/smplx.h"
#include "test_body_utils.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

namespace J = body::smplx_joint;
using body::Smplx;
using body::SmplxInput;

at::Tensor mirror_x(const at::Tensor& v) { return v * at::tensor({-1.0, 1.0, 1.0}, v.options()); }
at::Tensor mirrored_joints() {
  return at::tensor(std::vector<int64_t>(body::kSmplxMirroredJoints.begin(), body::kSmplxMirroredJoints.end()));
}

body::SmplxOptions options(bool pca) {
  body::SmplxOptions o;
  o.use_pca = pca;
  o.dtype = at::kDouble;
  return o;
}

TEST(BodyProcedural, IsDeterministicAndInTheSmplxLayout) {
  const auto& b = procedural_body();
  const body::ProceduralBody again = body::make_procedural_body();
  EXPECT_TRUE(again.smplx.v_template.equal(b.smplx.v_template) && again.smplx.faces.equal(b.smplx.faces));
  const auto& d = b.smplx;
  EXPECT_EQ(d.parents, std::vector<int64_t>(body::kSmplxParents.begin(), body::kSmplxParents.end()));
  const at::Tensor joints = d.j_regressor.matmul(d.v_template);
  const auto x = [&](int64_t j) { return joints[j][0].item<double>(); };
  const auto y = [&](int64_t j) { return joints[j][1].item<double>(); };
  const auto z = [&](int64_t j) { return joints[j][2].item<double>(); };
  // Left joints at +x, their mirrors at -x, centre joints on x = 0.
  for (int64_t j = 0; j < 55; ++j) {
    const int64_t m = body::kSmplxMirroredJoints[j];
    if (m == j)
      EXPECT_NEAR(x(j), 0.0, 1e-12) << body::kSmplxJointNames[j];
    else if (std::string(body::kSmplxJointNames[j]).rfind("left", 0) == 0)
      EXPECT_GT(x(j), 0.03) << body::kSmplxJointNames[j];
  }
  // A standing T-pose: head over neck over spine over pelvis over knees over ankles; arms out to the wrists.
  for (const auto& [upper, lower] : std::vector<std::pair<int64_t, int64_t>>{{J::kHead, J::kNeck},
                                                                             {J::kNeck, J::kSpine3},
                                                                             {J::kSpine3, J::kSpine2},
                                                                             {J::kSpine2, J::kSpine1},
                                                                             {J::kSpine1, J::kPelvis},
                                                                             {J::kPelvis, J::kLeftHip},
                                                                             {J::kLeftHip, J::kLeftKnee},
                                                                             {J::kLeftKnee, J::kLeftAnkle},
                                                                             {J::kLeftEye, J::kJaw}})
    EXPECT_GT(y(upper), y(lower) + 0.02) << body::kSmplxJointNames[upper] << " over " << body::kSmplxJointNames[lower];
  for (const auto& [outer, inner] : std::vector<std::pair<int64_t, int64_t>>{{J::kLeftShoulder, J::kLeftCollar},
                                                                             {J::kLeftElbow, J::kLeftShoulder},
                                                                             {J::kLeftWrist, J::kLeftElbow},
                                                                             {26, 25},
                                                                             {27, 26},
                                                                             {25, J::kLeftWrist}})
    EXPECT_GT(x(outer), x(inner) + 0.01) << body::kSmplxJointNames[outer];
  EXPECT_GT(z(J::kLeftFoot), z(J::kLeftAnkle) + 0.05);  // feet point forward
  EXPECT_GT(z(39), z(37) + 0.03);                       // the thumb points forward
  EXPECT_GT(z(J::kLeftEye), z(J::kHead) + 0.05);
  const double height = (d.v_template.select(1, 1).max() - d.v_template.select(1, 1).min()).item<double>();
  EXPECT_NEAR(height, 1.76, 0.05);
}

// One subdivision step on a cube, the smallest closed cage: the counts of vertex, edge and face points, affine
// stencil rows (weights sum to 1) and a mirror map that is an involution and matches the subdivided positions.
TEST(BodyProcedural, CatmullClarkStepOnACube) {
  namespace P = body::procedural;
  std::vector<P::Vec3> corners;
  for (int i = 0; i < 8; ++i) corners.push_back({i & 1 ? 1.0 : -1.0, i & 2 ? 1.0 : -1.0, i & 4 ? 1.0 : -1.0});
  P::PolyMesh cube;
  cube.vertex_count = 8;
  cube.faces = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}};
  cube.charts = {0, 1, 2, 3, 4, 5};
  const P::Subdivided fine = P::catmull_clark(cube, P::mirror_by_position(corners));
  EXPECT_EQ(fine.mesh.vertex_count, 8 + 12 + 6);
  ASSERT_EQ(fine.mesh.faces.size(), 24u);
  for (size_t q = 0; q < fine.mesh.faces.size(); ++q) {
    EXPECT_EQ(fine.mesh.faces[q].size(), 4u);
    EXPECT_EQ(fine.mesh.charts[q], cube.charts[q / 4]);  // each coarse face becomes its own four quads
  }
  at::Tensor coarse = at::empty({8, 3}, at::kDouble);
  for (int i = 0; i < 8; ++i)
    for (int k = 0; k < 3; ++k) coarse[i][k] = corners[i][k];
  EXPECT_TRUE(fine.stencil.apply(at::ones({8, 1}, at::kDouble)).sub(1).abs().max().item<double>() < 1e-15);
  const at::Tensor points = fine.stencil.apply(coarse);
  const at::Tensor mirror = at::tensor(fine.mirror, at::kLong);
  EXPECT_TRUE(mirror.index_select(0, mirror).equal(at::arange(26, at::kLong)));
  EXPECT_LT(max_difference(points.index_select(0, mirror), mirror_x(points)), 1e-15);
  // Vertex points of a cube's corners (valence 3) move to 5/9 of the way: (Q + 2R + 0 S) / 3.
  EXPECT_NEAR(points[7][0].item<double>(), 5.0 / 9.0, 1e-15);
}

TEST(BodyProcedural, IsAClosedOutwardSurfaceOfThreeComponents) {
  const auto& d = procedural_body().smplx;
  const int64_t v = d.v_template.size(0);
  EXPECT_TRUE(closed_and_oriented(d.faces, v));
  EXPECT_EQ(v - body::mesh_edges(d.faces, v).edges.size(0) + d.faces.size(0), 6);     // three spheres
  EXPECT_EQ(at::bincount(d.faces.flatten(), {}, v).min().item<int64_t>() > 0, true);  // no unused vertex
  // Outward: the signed volume is positive, and about a human's (60-80 litres).
  const at::Tensor p = d.v_template.index_select(0, d.faces.flatten()).view({-1, 3, 3});
  const double volume =
      at::linalg_cross(p.select(1, 1), p.select(1, 2), -1).mul(p.select(1, 0)).sum().item<double>() / 6;
  EXPECT_GT(volume, 0.055);
  EXPECT_LT(volume, 0.085);
  const at::Tensor area =
      at::linalg_cross(p.select(1, 1) - p.select(1, 0), p.select(1, 2) - p.select(1, 0), -1).norm(2, 1);
  EXPECT_GT(area.min().item<double>(), 1e-8);  // no degenerate triangle
}

TEST(BodyProcedural, WeightsAndRegressorAreWellFormedAndSmooth) {
  const auto& d = procedural_body().smplx;
  EXPECT_GE(d.weights.min().item<double>(), 0.0);
  EXPECT_LT(max_difference(d.weights.sum(1), at::ones({d.weights.size(0)}, at::kDouble)), 1e-12);
  EXPECT_GE(d.j_regressor.min().item<double>(), 0.0);
  EXPECT_LT(max_difference(d.j_regressor.sum(1), at::ones({55}, at::kDouble)), 1e-12);
  // Smooth: no edge crosses a hard boundary between joints (that would change the weights by 2 in L1). The
  // largest changes are where the lips part (head above, jaw below) and along the short finger segments.
  const at::Tensor e = body::mesh_edges(d.faces, d.v_template.size(0)).edges;
  const at::Tensor jump =
      (d.weights.index_select(0, e.select(1, 0)) - d.weights.index_select(0, e.select(1, 1))).abs().sum(1);
  EXPECT_LT(jump.max().item<double>(), 0.5);
  const at::Tensor on_body = d.part_labels.index_select(0, e.select(1, 0)) == 0;
  EXPECT_LT(jump.masked_select(on_body).max().item<double>(), 0.4);
  // Every joint drives some vertices, except the wrists' role is shared with the palms.
  const at::Tensor dominant = at::bincount(body::dominant_joints(d.weights), {}, 55);
  for (int64_t j = 0; j < 55; ++j) EXPECT_GT(dominant[j].item<int64_t>(), 0) << body::kSmplxJointNames[j];
}

TEST(BodyProcedural, IsExactlyLeftRightSymmetric) {
  const auto& b = procedural_body();
  const auto& d = b.smplx;
  const at::Tensor m = b.mirrored_vertices;
  const at::Tensor mj = mirrored_joints();
  EXPECT_TRUE(m.index_select(0, m).equal(at::arange(m.size(0))));  // an involution
  EXPECT_LT(max_difference(d.v_template.index_select(0, m), mirror_x(d.v_template)), 1e-12);
  EXPECT_LT(max_difference(d.weights.index_select(0, m).index_select(1, mj), d.weights), 1e-12);
  EXPECT_LT(max_difference(d.j_regressor.index_select(0, mj).index_select(1, m), d.j_regressor), 1e-15);
  // Mirrored faces, with reversed winding, are faces.
  std::set<std::array<int64_t, 3>> faces;
  const auto canonical = [](std::array<int64_t, 3> t) {
    std::rotate(t.begin(), std::min_element(t.begin(), t.end()), t.end());
    return t;
  };
  const auto f = d.faces.accessor<int64_t, 2>();
  const auto mm = m.accessor<int64_t, 1>();
  for (int64_t i = 0; i < d.faces.size(0); ++i) faces.insert(canonical({f[i][0], f[i][1], f[i][2]}));
  for (int64_t i = 0; i < d.faces.size(0); ++i)
    ASSERT_TRUE(faces.count(canonical({mm[f[i][2]], mm[f[i][1]], mm[f[i][0]]})));
  // Shape directions are symmetric; expression directions map onto their mirror columns.
  const auto mirror_dirs = [&](const at::Tensor& dirs) {
    return mirror_x(dirs.index_select(0, m).transpose(1, 2)).transpose(1, 2);
  };
  EXPECT_LT(max_difference(mirror_dirs(d.shapedirs), d.shapedirs), 1e-12);
  const at::Tensor columns = at::tensor(b.mirrored_expressions);
  EXPECT_LT(max_difference(mirror_dirs(d.exprdirs).index_select(2, columns), d.exprdirs), 1e-12);
  EXPECT_GT(max_difference(d.exprdirs.select(2, 2), d.exprdirs.select(2, 3)), 1e-3);  // the one-sided smiles differ
  EXPECT_TRUE(d.part_labels.index_select(0, m).equal(
      at::tensor({0, 1, 3, 2}, at::kInt).to(at::kByte).index_select(0, d.part_labels.to(at::kLong))));
}

TEST(BodyProcedural, MirroredPosesGiveMirroredBodies) {
  const auto& b = procedural_body();
  const Smplx model(b.smplx, options(/*pca=*/false));
  at::manual_seed(17);
  SmplxInput in;
  in.betas = at::randn({1, 10}, at::kDouble);
  in.pose.expression = at::randn({1, 10}, at::kDouble);
  in.pose.transl = at::randn({1, 3}, at::kDouble);
  in.pose.global_orient = 0.4 * at::randn({1, 3}, at::kDouble);
  in.pose.body_pose = 0.4 * at::randn({1, 63}, at::kDouble);
  in.pose.jaw_pose = 0.2 * at::randn({1, 3}, at::kDouble);
  in.pose.leye_pose = 0.2 * at::randn({1, 3}, at::kDouble);
  in.pose.reye_pose = 0.2 * at::randn({1, 3}, at::kDouble);
  in.pose.left_hand_pose = 0.4 * at::randn({1, 45}, at::kDouble);
  in.pose.right_hand_pose = 0.4 * at::randn({1, 45}, at::kDouble);
  const auto out = model->forward(in);
  // Mirror every joint's rotation (x, -y, -z), swap the sides, mirror the expression and the translation.
  const at::Tensor pose =
      (out.full_pose * at::tensor({1.0, -1.0, -1.0}, at::kDouble)).index_select(1, mirrored_joints());
  const at::Tensor mean = at::cat(
      {at::zeros({25, 3}, at::kDouble), b.smplx.hands_mean_left.view({15, 3}), b.smplx.hands_mean_right.view({15, 3})});
  SmplxInput mirrored;
  mirrored.betas = in.betas;
  mirrored.pose.expression = in.pose.expression.index_select(1, at::tensor(b.mirrored_expressions));
  mirrored.pose.transl = mirror_x(in.pose.transl);
  mirrored.pose.global_orient = pose.select(1, 0);
  mirrored.pose.body_pose = pose.narrow(1, 1, 21).flatten(1);
  mirrored.pose.jaw_pose = pose.select(1, 22);
  mirrored.pose.leye_pose = pose.select(1, 23);
  mirrored.pose.reye_pose = pose.select(1, 24);
  mirrored.pose.left_hand_pose = (pose - mean).narrow(1, 25, 15).flatten(1);
  mirrored.pose.right_hand_pose = (pose - mean).narrow(1, 40, 15).flatten(1);
  const auto back = model->forward(mirrored);
  EXPECT_LT(max_difference(back.vertices[0].index_select(0, b.mirrored_vertices), mirror_x(out.vertices[0])), 1e-10);
  EXPECT_LT(max_difference(back.joints[0].index_select(0, mirrored_joints()), mirror_x(out.joints[0])), 1e-10);
  // With PCA, the same coefficients give mirror-image hands.
  const Smplx pca(b.smplx, options(true));
  SmplxInput hands;
  hands.pose.left_hand_pose = at::randn({1, 6}, at::kDouble);
  hands.pose.right_hand_pose = hands.pose.left_hand_pose;
  const at::Tensor v = pca->forward(hands).vertices[0];
  EXPECT_LT(max_difference(v.index_select(0, b.mirrored_vertices), mirror_x(v)), 1e-10);
}

TEST(BodyProcedural, FingersAreSeparate) {
  const auto& d = procedural_body().smplx;
  const at::Tensor dominant = body::dominant_joints(d.weights);
  // Distal segments of neighbouring fingers (index, middle, ring, pinky) do not touch.
  for (const auto& [a, b] : std::vector<std::pair<int64_t, int64_t>>{{27, 30}, {30, 36}, {36, 33}, {42, 45}}) {
    const at::Tensor pa = d.v_template.index_select(0, (dominant == a).nonzero().flatten());
    const at::Tensor pb = d.v_template.index_select(0, (dominant == b).nonzero().flatten());
    ASSERT_GT(pa.size(0), 20);
    EXPECT_GT(at::cdist(pa, pb).min().item<double>(), 0.002)
        << body::kSmplxJointNames[a] << " and " << body::kSmplxJointNames[b];
  }
}

TEST(BodyProcedural, TheJawOpensTheMouthAndTheEyesTurnInPlace) {
  const auto& d = procedural_body().smplx;
  const Smplx model(d, options(true));
  SmplxInput open;
  open.pose.jaw_pose = at::tensor({0.3, 0.0, 0.0}, at::kDouble).view({1, 3});
  open.pose.leye_pose = at::tensor({0.0, 0.8, 0.0}, at::kDouble).view({1, 3});
  body::SmplxOptions flat = options(true);
  flat.flat_hand_mean = true;
  const at::Tensor v = Smplx(d, flat)->forward(open).vertices[0];
  const at::Tensor moved = (v - d.v_template).norm(2, 1);
  const at::Tensor jaw_led = d.weights.select(1, J::kJaw) > 0.5;
  EXPECT_GT(jaw_led.sum().item<int64_t>(), 200);
  EXPECT_GT(moved.masked_select(jaw_led).max().item<double>(), 0.02);  // the chin drops by centimetres
  // Opening the jaw separates the lips: the mouth has an opening, not a sealed surface.
  const at::Tensor lower_lip = (jaw_led & (d.v_template.select(1, 2) > 0.08)).nonzero().flatten();
  ASSERT_GT(lower_lip.size(0), 0);
  EXPECT_LT((v.index_select(0, lower_lip).select(1, 1) - d.v_template.index_select(0, lower_lip).select(1, 1))
                .max()
                .item<double>(),
            -0.005);
  const at::Tensor head_only = d.weights.select(1, J::kHead) == 1;
  EXPECT_LT(moved.masked_select(head_only).max().item<double>(), 1e-12);
  // The left eyeball turns about its centre: every vertex stays at the same distance from the eye joint.
  const at::Tensor eye = (d.weights.select(1, J::kLeftEye) == 1).nonzero().flatten();
  const at::Tensor centre = d.j_regressor[J::kLeftEye].matmul(d.v_template);
  const at::Tensor radius = (d.v_template.index_select(0, eye) - centre).norm(2, 1);
  EXPECT_LT((radius - radius.mean()).abs().max().item<double>(), 1e-12);  // a sphere about the joint
  EXPECT_LT(max_difference((v.index_select(0, eye) - centre).norm(2, 1), radius), 1e-12);
  EXPECT_GT(moved.index_select(0, eye).max().item<double>(), 0.005);
}

TEST(BodyProcedural, ShapeAndExpressionDirectionsDoWhatTheySay) {
  const auto& d = procedural_body().smplx;
  EXPECT_EQ(d.shapedirs.size(2), 10);
  EXPECT_EQ(d.exprdirs.size(2), 10);
  for (int64_t k = 0; k < 10; ++k)
    EXPECT_GT(d.shapedirs.select(2, k).abs().max().item<double>(), 0.005) << "shape " << k;
  // Height: +1 adds about 7 cm.
  const at::Tensor taller = d.v_template + d.shapedirs.select(2, 0);
  const auto height = [](const at::Tensor& v) { return (v.select(1, 1).max() - v.select(1, 1).min()).item<double>(); };
  EXPECT_NEAR(height(taller) - height(d.v_template), 0.07, 0.005);
  // Expressions move the face only: nothing the head and jaw do not mostly carry, never an eyeball.
  const at::Tensor face = d.part_labels == static_cast<int64_t>(body::BodyPart::kFace);
  const at::Tensor carried = d.weights.select(1, J::kHead) + d.weights.select(1, J::kJaw);
  for (int64_t k = 0; k < 10; ++k) {
    const at::Tensor size = d.exprdirs.select(2, k).norm(2, 1);
    EXPECT_GT(size.masked_select(face).max().item<double>(), 0.003) << "expression " << k;
    EXPECT_EQ(size.masked_select(carried <= 0.5).max().item<double>(), 0.0) << "expression " << k;
  }
}

TEST(BodyProcedural, UvsLieInTheUnitSquareWithoutOverlapsOfArea) {
  const auto& d = procedural_body().smplx;
  EXPECT_GE(d.uvs.min().item<double>(), 0.0);
  EXPECT_LE(d.uvs.max().item<double>(), 1.0);
  const at::Tensor t = d.uvs.index_select(0, d.uv_faces.flatten()).view({-1, 3, 2});
  const at::Tensor a = t.select(1, 1) - t.select(1, 0), b = t.select(1, 2) - t.select(1, 0);
  const at::Tensor area = 0.5 * (a.select(1, 0) * b.select(1, 1) - a.select(1, 1) * b.select(1, 0)).abs();
  // The charts fill a good part of the square and cannot overlap much: their total area stays below 1.
  EXPECT_GT(area.sum().item<double>(), 0.3);
  EXPECT_LT(area.sum().item<double>(), 1.0);
  EXPECT_GT((area > 0).to(at::kDouble).mean().item<double>(), 0.999);
}

TEST(BodyProcedural, HandsInTheManoLayout) {
  const auto& b = procedural_body();
  for (const auto* hand : {&b.mano_left, &b.mano_right}) {
    EXPECT_EQ(hand->j_regressor.size(0), 16);
    EXPECT_LT(max_difference(hand->weights.sum(1), at::ones({hand->weights.size(0)}, at::kDouble)), 1e-12);
    EXPECT_LT(max_difference(hand->j_regressor.sum(1), at::ones({16}, at::kDouble)), 1e-12);
    // Open at the wrist: some edges have one face only.
    const int64_t v = hand->v_template.size(0);
    const at::Tensor e = hand->faces.index_select(1, at::tensor({0, 1, 1, 2, 2, 0})).view({-1, 2});
    EXPECT_LT(body::mesh_edges(hand->faces, v).edges.size(0) * 2, e.size(0) + 200);
    EXPECT_GT(body::mesh_edges(hand->faces, v).edges.size(0) * 2, e.size(0));
  }
  EXPECT_TRUE(b.mano_left.v_template.equal(b.smplx.v_template.index_select(0, b.hand_vertex_ids.left)));
  EXPECT_TRUE(b.hand_vertex_ids.left.equal(b.mirrored_vertices.index_select(0, b.hand_vertex_ids.right)));
  EXPECT_TRUE(b.mano_left.faces.equal(b.mano_right.faces.flip(1)));
}

TEST(BodyProcedural, WrittenFilesLoadIntoTheSameModels) {
  ScratchFolder folder;
  const auto& b = procedural_body();
  body::write_procedural_body(b, folder.str(), false);
  expect_error([&] { body::write_procedural_body(b, folder.str(), false); }, {"refusing to overwrite"});
  const Smplx from_file(folder.file("procedural_smplx.npz"), options(true));
  const Smplx in_memory(b.smplx, options(true));
  SmplxInput in;
  in.pose.body_pose = 0.3 * at::randn({1, 63}, at::kDouble);
  EXPECT_TRUE(from_file->forward(in).vertices.equal(in_memory->forward(in).vertices));
  const body::ManoModelData left = body::ManoModelData::load(folder.file("procedural_mano_left.npz"));
  EXPECT_TRUE(left.shapedirs.equal(b.mano_left.shapedirs));
  const int64_t v = b.smplx.v_template.size(0);
  const body::HandVertexIds ids = body::load_hand_vertex_ids(folder.file("procedural_MANO_SMPLX_vertex_ids.npz"), v);
  EXPECT_TRUE(ids.left.equal(b.hand_vertex_ids.left) && ids.right.equal(b.hand_vertex_ids.right));
  EXPECT_TRUE(body::load_face_vertex_ids(folder.file("procedural_face_vertex_ids.npy"), v).equal(b.face_vertex_ids));
}

}  // namespace
}  // namespace sfgs::testing
