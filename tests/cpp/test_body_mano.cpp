// The MANO layer (csrc/body/mano.h): agreement with the SMPL-X hands, the left-hand shapedirs repair, PCA and mean,
// gradients, files, on the procedural hands and on the CC0 Anny MANO-layout stand-ins.
#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "body/mano.h"
#include "body/parts.h"
#include "body/skeleton.h"
#include "body/smplx.h"
#include "io/npz.h"
#include "test_body_utils.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using body::Mano;
using body::ManoInput;
using body::ManoModelData;
using body::ManoOptions;
using body::Side;

ManoOptions mano_options(bool pca, bool flat_hand_mean) {
  ManoOptions o;
  o.use_pca = pca;
  o.flat_hand_mean = flat_hand_mean;
  o.dtype = at::kDouble;
  return o;
}

// A MANO hand posed with `pose` (45) and wrist rotation `wrist` equals the body posed the same way, on the vertices
// whose body weights lie entirely on that hand's joints (the others also follow the forearm in the body).
void expect_mano_matches_the_body(const body::SmplxModelData& smplx, const ManoModelData& hand, const at::Tensor& ids,
                                  Side side) {
  at::manual_seed(5);
  const at::Tensor pose = 0.3 * at::randn({1, 45}, at::kDouble), wrist = 0.4 * at::randn({1, 3}, at::kDouble);
  body::SmplxOptions so;
  so.use_pca = false;
  so.flat_hand_mean = true;
  so.dtype = at::kDouble;
  body::SmplxInput in;
  (side == Side::kLeft ? in.pose.left_hand_pose : in.pose.right_hand_pose) = pose;
  in.pose.body_pose = at::zeros({1, 63}, at::kDouble);
  in.pose.body_pose.narrow(1, 3 * (body::smplx_hand_joint(side, 0) - 1), 3).copy_(wrist);
  const at::Tensor body_vertices = body::Smplx(smplx, so)->forward(in).vertices[0].index_select(0, ids);
  ManoInput mi;
  mi.hand_pose = pose;
  mi.global_orient = wrist;
  const auto out = Mano(hand, mano_options(false, true))->forward(mi);
  std::vector<int64_t> joints;
  for (int64_t k = 0; k < body::kManoJointCount; ++k) joints.push_back(body::smplx_hand_joint(side, k));
  const at::Tensor only_hand =
      (smplx.weights.index_select(0, ids).index_select(1, at::tensor(joints, at::kLong)).sum(1) > 1 - 1e-12);
  ASSERT_GT(only_hand.sum().item<int64_t>(), ids.size(0) / 2);
  const at::Tensor keep = only_hand.nonzero().flatten();
  EXPECT_LT(max_difference(out.vertices[0].index_select(0, keep), body_vertices.index_select(0, keep)), 1e-9);
  // MANO's joints are the body's hand joints.
  EXPECT_LT(max_difference(out.rest_joints[0],
                           smplx.j_regressor.matmul(smplx.v_template).index_select(0, at::tensor(joints))),
            1e-9);
}

TEST(BodyMano, ProceduralHandsMoveLikeTheBodysHands) {
  const auto& body = procedural_body();
  expect_mano_matches_the_body(body.smplx, body.mano_left, body.hand_vertex_ids.left, Side::kLeft);
  expect_mano_matches_the_body(body.smplx, body.mano_right, body.hand_vertex_ids.right, Side::kRight);
}

TEST(BodyMano, AnnyHandsMoveLikeTheBodysHands) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  const std::string folder = shared_bodies_folder();
  const body::HandVertexIds ids =
      body::load_hand_vertex_ids(folder + "/MANO_SMPLX_vertex_ids.npz", anny_smplx().v_template.size(0));
  const ManoModelData left = ManoModelData::load(folder + "/anny_mano_left.npz");
  const ManoModelData right = ManoModelData::load(folder + "/anny_mano_right.npz");
  expect_mano_matches_the_body(anny_smplx(), left, ids.left, Side::kLeft);
  expect_mano_matches_the_body(anny_smplx(), right, ids.right, Side::kRight);
  // Anny's hands are true mirror images: the left-hand shapedirs repair must leave them alone.
  ManoModelData repaired = left;
  EXPECT_FALSE(body::repair_left_mano_shapedirs(repaired, right));
  EXPECT_TRUE(repaired.shapedirs.equal(left.shapedirs));
  // The file's rest joints ('J') are the regressor on the template.
  const at::Tensor j = io::NpzArchive(folder + "/anny_mano_right.npz").read("J");
  EXPECT_LT(max_difference(right.j_regressor.matmul(right.v_template), j), 1e-8);
}

TEST(BodyMano, TheLeftHandShapedirsRepairRestoresMirrorSymmetry) {
  const auto& body = procedural_body();
  // The official MANO_LEFT's bug: its shapedirs x components are the right hand's.
  ManoModelData bugged = body.mano_left;
  bugged.shapedirs = bugged.shapedirs.clone();
  bugged.shapedirs.select(1, 0).copy_(body.mano_right.shapedirs.select(1, 0));
  at::manual_seed(9);
  ManoInput in;
  in.betas = at::randn({1, 10}, at::kDouble);
  const auto mirror_x = [](at::Tensor v) { return v * at::tensor({-1.0, 1.0, 1.0}, at::kDouble); };
  const at::Tensor right = Mano(body.mano_right, mano_options(true, true))->forward(in).vertices;
  EXPECT_GT(max_difference(Mano(bugged, mano_options(true, true))->forward(in).vertices, mirror_x(right)), 1e-3);
  EXPECT_TRUE(body::repair_left_mano_shapedirs(bugged, body.mano_right));
  EXPECT_LT(max_difference(Mano(bugged, mano_options(true, true))->forward(in).vertices, mirror_x(right)), 1e-12);
  EXPECT_FALSE(body::repair_left_mano_shapedirs(bugged, body.mano_right));  // repairing twice does nothing
}

TEST(BodyMano, PcaFlatHandMeanAndRotations) {
  const ManoModelData& hand = procedural_body().mano_right;
  at::manual_seed(11);
  ManoInput in;
  in.hand_pose = 0.5 * at::randn({2, 6}, at::kDouble);
  in.global_orient = 0.3 * at::randn({2, 3}, at::kDouble);
  in.betas = at::randn({2, 10}, at::kDouble);
  const auto pca = Mano(hand, mano_options(true, false))->forward(in);
  ManoInput full = in;
  full.hand_pose = in.hand_pose.matmul(hand.hands_components.narrow(0, 0, 6)).view({2, 15, 3});
  const auto direct = Mano(hand, mano_options(false, false))->forward(full);
  EXPECT_LT(max_difference(pca.vertices, direct.vertices), 1e-12);
  EXPECT_LT(max_difference(pca.full_pose.narrow(1, 1, 15).flatten(1), full.hand_pose.flatten(1) + hand.hands_mean),
            1e-14);
  // flat_hand_mean: a zero pose is the flat template; otherwise the mean pose.
  const auto flat = Mano(hand, mano_options(true, true))->forward(ManoInput{});
  EXPECT_LT(max_difference(flat.vertices[0], hand.v_template), 1e-12);
  const auto relaxed = Mano(hand, mano_options(true, false))->forward(ManoInput{});
  EXPECT_GT(max_difference(relaxed.vertices[0], hand.v_template), 1e-3);
  ManoInput by_matrix;
  by_matrix.betas = in.betas;
  by_matrix.rotations = pca.rotations;
  EXPECT_LT(max_difference(Mano(hand, mano_options(true, false))->forward(by_matrix).vertices, pca.vertices), 1e-12);
}

TEST(BodyMano, GradientsMatchFiniteDifferences) {
  const Mano model(procedural_body().mano_left, mano_options(true, false));
  at::manual_seed(13);
  ManoInput in;
  in.betas = at::randn({1, 10}, at::kDouble).requires_grad_(true);
  in.global_orient = (0.3 * at::randn({1, 3}, at::kDouble)).requires_grad_(true);
  in.hand_pose = (0.3 * at::randn({1, 6}, at::kDouble)).requires_grad_(true);
  in.transl = at::randn({1, 3}, at::kDouble).requires_grad_(true);
  const at::Tensor w = at::randn({1, model->vertex_count(), 3}, at::kDouble);
  const auto loss = [&] { return (model->forward(in).vertices * w).sum(); };
  loss().backward();
  for (at::Tensor* t : {&in.betas, &in.global_orient, &in.hand_pose, &in.transl}) {
    const at::Tensor values = t->detach();
    for (int64_t k : {int64_t{0}, values.numel() - 1}) {
      const double fd = central_difference([&] { return loss().item<double>(); }, values, k, 1e-6);
      EXPECT_NEAR(t->grad().flatten()[k].item<double>(), fd, 1e-6 * std::max(1.0, std::abs(fd)));
    }
  }
}

TEST(BodyMano, FilesRoundTripAndForeignFilesAreClearErrors) {
  ScratchFolder folder;
  const ManoModelData& hand = procedural_body().mano_right;
  hand.save(folder.file("hand.npz"), false);
  const ManoModelData back = ManoModelData::load(folder.file("hand.npz"));
  EXPECT_TRUE(back.v_template.equal(hand.v_template) && back.faces.equal(hand.faces) &&
              back.shapedirs.equal(hand.shapedirs) && back.weights.equal(hand.weights));
  EXPECT_EQ(back.parents, std::vector<int64_t>(body::kManoParents.begin(), body::kManoParents.end()));
  procedural_body().smplx.save(folder.file("body.npz"), false);
  expect_error([&] { ManoModelData::load(folder.file("body.npz")); }, {"body.npz", "regresses 55 joints; MANO has 16"});
  expect_error([&] { Mano(folder.file("MANO_RIGHT.pkl")); }, {"MANO_RIGHT.pkl", "does not exist"});
  const Mano model(hand, mano_options(true, false));
  ManoInput in;
  in.hand_pose = at::zeros({1, 45}, at::kDouble);
  expect_error([&] { model->forward(in); },
               {"Mano: hand_pose (PCA coefficients) must be a Double tensor of shape [1, 6]"});
}

}  // namespace
}  // namespace sfgs::testing
