// The avatar's MANO hand residual and its bodies: the residual is MANO's geometry against SMPL-X's in the canonical
// frame relative to the wrist, carried by the skinning; the left-hand shapedirs repair; AvatarBody::load from the
// official file layouts (the procedural body written out, and the CC0 Anny stand-ins when present).
#include <string>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "body/parts.h"
#include "body/procedural_body.h"
#include "body/rotations.h"
#include "body/skeleton.h"
#include "data/motions.h"
#include "model/avatar.h"
#include "model/hand_residual.h"
#include "train/run_folder.h"
#include "test_avatar_utils.h"
#include "test_body_utils.h"

namespace sfgs::testing {
namespace {

using model::Avatar;
using model::AvatarBody;
using model::AvatarConfig;
using model::AvatarOutput;

constexpr double kBump = 0.003;  // metres

// The procedural body whose right MANO hand has a bump of kBump along +y on its 20 most distal vertices (none of
// them used by the wrist regressor) and no shape space, so the fitted MANO shape is its template.
struct BumpedHand {
  AvatarBody body;
  at::Tensor bumped;  // (20) MANO vertex indices
};

BumpedHand bumped_right_hand() {
  BumpedHand b{procedural_avatar_body(), {}};
  body::ManoModelData& right = b.body.mano_right;
  const at::Tensor free_of_wrist = right.j_regressor[0].eq(0);
  const at::Tensor x = right.v_template.select(1, 0).masked_fill(free_of_wrist.logical_not(), 1e9);
  b.bumped = std::get<1>(x.topk(20, 0, /*largest=*/false));  // the right hand reaches towards -x
  right.v_template = right.v_template.clone();
  right.v_template.select(1, 1).index_add_(0, b.bumped, at::full({20}, kBump, at::kDouble));
  right.shapedirs = at::zeros_like(right.shapedirs);
  return b;
}

// A motion's absolute hand poses (the library's, AMASS's) reach an avatar in its own convention: an avatar that adds
// the body's mean hand (the default) and one that takes absolute hands pose the same fingers; poses relative to the
// mean reach the absolute one with the mean added back. The built-in body's mean hand is not zero.
TEST(AvatarHands, AbsoluteHandPosesArePutInTheAvatarsConvention) {
  const model::AvatarBody body = procedural_avatar_body();
  ASSERT_GT(body.smplx.hands_mean_left.abs().max().item<double>(), 0.05);
  model::AvatarConfig relative = small_config(), absolute = small_config();
  absolute.flat_hand_mean = true;
  const at::Tensor betas = at::zeros({10});
  torch::manual_seed(3);
  model::Avatar a(body, betas, relative);
  torch::manual_seed(3);
  model::Avatar b(body, betas, absolute);
  const body::SmplxPose wave = data::motion_pose("wave", 0.5, relative.num_expression_coeffs);
  at::NoGradGuard no_grad;
  const auto fingers = [](model::Avatar& avatar, const body::SmplxPose& pose) {
    return avatar->forward(pose, std::nullopt).posed_vertices;
  };
  const at::Tensor expected = fingers(b, train::hands_for_avatar(b, wave, true));
  EXPECT_LT((fingers(a, train::hands_for_avatar(a, wave, true)) - expected).abs().max().item<double>(), 1e-5);
  EXPECT_GT((fingers(a, wave) - expected).abs().max().item<double>(), 1e-3) << "unconverted, the mean is added twice";
  const body::SmplxPose to_mean = train::hands_for_avatar(a, wave, true);
  EXPECT_LT((fingers(b, train::hands_for_avatar(b, to_mean, false)) - expected).abs().max().item<double>(), 1e-5);
}

TEST(AvatarHands, ResidualIsMANOMinusSMPLXInTheCanonicalFrame) {
  const BumpedHand b = bumped_right_hand();
  AvatarConfig config = small_config();
  config.flat_hand_mean = true;
  Avatar avatar(b.body, at::zeros({10}), config);
  const at::Tensor bumped = b.body.hand_vertex_ids.right.index_select(0, b.bumped);
  at::Tensor expected = at::zeros({avatar->gaussian_count(), 3});
  expected.select(1, 1).index_fill_(0, bumped, kBump);

  // Rest pose: the residual is the bump, and the Gaussians sit on the bumped hand.
  body::SmplxPose rest;
  rest.left_hand_pose = at::zeros({15, 3});
  rest.right_hand_pose = at::zeros({15, 3});
  const AvatarOutput at_rest = avatar->forward(rest, kTestTime);
  EXPECT_LT(max_abs_difference(at_rest.hand_residual, expected), 1e-6);
  EXPECT_LT(max_abs_difference(at_rest.means - at_rest.posed_vertices, expected), 1e-6);

  // Posed: the canonical residual is unchanged (the procedural hands have no pose correctives) and the skinning
  // carries it rigidly with the fingertips.
  const body::SmplxPose posed = test_pose(31, 0.5, /*hands=*/true);
  const AvatarOutput out = avatar->forward(posed, kTestTime);
  EXPECT_LT(max_abs_difference(out.hand_residual, expected), 1e-6);
  const at::Tensor moved = (out.means - out.posed_vertices).index_select(0, bumped);
  const at::Tensor length = moved.pow(2).sum(1).sqrt();  // blending two finger joints may shorten it a little
  EXPECT_GT(length.min().item<double>(), 0.8 * kBump);
  EXPECT_LT(length.max().item<double>(), kBump * (1 + 1e-4));
  EXPECT_GT(max_abs_difference(moved, expected.index_select(0, bumped)), 1e-4);  // it turned with the fingers
}

TEST(AvatarHands, ResidualIgnoresWhereTheMANOModelSits) {
  AvatarBody shifted = procedural_avatar_body();
  for (body::ManoModelData* mano : {&shifted.mano_left, &shifted.mano_right})
    mano->v_template = mano->v_template + at::tensor({0.05, -0.3, 0.2}, at::kDouble);
  Avatar avatar(shifted, subject_betas(), small_config());
  EXPECT_LT(avatar->forward(test_pose(32, 0.5, true), kTestTime).hand_residual.abs().max().item<double>(), 1e-5);
}

TEST(AvatarHands, LeftShapedirsAreRepaired) {
  AvatarBody broken = procedural_avatar_body();
  broken.mano_left.shapedirs = broken.mano_left.shapedirs.clone();
  broken.mano_left.shapedirs.select(1, 0).copy_(broken.mano_right.shapedirs.select(1, 0));
  body::ManoModelData check = broken.mano_left;
  ASSERT_TRUE(body::repair_left_mano_shapedirs(check, broken.mano_right));  // the official files' bug

  Avatar good(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*good, 0.1, 33);
  Avatar repaired(broken, subject_betas(), small_config());
  copy_parameters(*good, *repaired);
  const body::SmplxPose pose = test_pose(33, 0.5, true);
  EXPECT_LT(max_abs_difference(good->forward(pose, kTestTime).hand_residual,
                               repaired->forward(pose, kTestTime).hand_residual),
            1e-6);
}

TEST(AvatarHands, LoadsTheOfficialFileLayouts) {
  const ScratchFolder folder;
  body::write_procedural_body(procedural_body(), folder.str(), /*overwrite=*/false);
  const std::string smplx = folder.file("procedural_smplx.npz"), left = folder.file("procedural_mano_left.npz"),
                    right = folder.file("procedural_mano_right.npz"),
                    ids = folder.file("procedural_MANO_SMPLX_vertex_ids.npz"),
                    face = folder.file("procedural_face_vertex_ids.npy");
  const AvatarBody loaded = AvatarBody::load(smplx, left, right, ids, face);
  ASSERT_TRUE(loaded.has_mano);
  EXPECT_TRUE(loaded.hand_vertex_ids.left.equal(procedural_avatar_body().hand_vertex_ids.left));
  EXPECT_TRUE(loaded.face_vertex_ids.equal(procedural_avatar_body().face_vertex_ids));

  Avatar built(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*built, 0.1, 34);
  Avatar from_files(loaded, subject_betas(), small_config());
  copy_parameters(*built, *from_files);
  const body::SmplxPose pose = test_pose(34, 0.5, true);
  const AvatarOutput a = built->forward(pose, kTestTime), b = from_files->forward(pose, kTestTime);
  EXPECT_LT(max_abs_difference(a.means, b.means), 1e-6);
  EXPECT_LT(max_abs_difference(a.colours, b.colours), 1e-6);

  expect_error([&] { AvatarBody::load(smplx, left, "", ids, ""); }, {"all three", "right ''"});
}

// The avatar's hand residual module.
const model::HandResidualImpl& hand_residual_of(const Avatar& avatar) {
  const auto module = std::dynamic_pointer_cast<model::HandResidualImpl>(avatar->named_children()["hand_residual"]);
  if (!module) throw std::runtime_error("the avatar has no hand residual");
  return *module;
}

// forward's linear map r = c + f D against MANO's forward pass and SMPL-X's correctives composed: the same residual
// and the same gradient through the hand poses, at large finger angles (the pose correctives' whole range), on the
// procedural body and the Anny stand-ins.
void expect_linear_map_is_the_composition(const AvatarBody& body, const std::string& label) {
  Avatar avatar(body, subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 36);  // a refining MLP that is not zero
  const model::HandResidualImpl& hands = hand_residual_of(avatar);
  // float32 (the avatar's dtype): the map is made in float64 and rounded once, the composition rounds at each step.
  const double bound = 2e-6;
  for (int64_t seed : {37, 38}) {
    at::manual_seed(seed);
    const at::Tensor left = (at::rand({15, 3}) * 3.0 - 1.5).requires_grad_(true);
    const at::Tensor right = (at::rand({15, 3}) * 3.0 - 1.5).requires_grad_(true);
    const at::Tensor fast = hands.forward(left, right), composed = hands.reference(left, right);
    EXPECT_GT(composed.abs().max().item<double>(), 1e-4) << label << ": a residual worth comparing";
    EXPECT_LT(max_abs_difference(fast, composed), bound) << label;
    const at::Tensor weights = at::randn(fast.sizes());
    const auto fast_grads = torch::autograd::grad({(fast * weights).sum()}, {left, right});
    const auto composed_grads = torch::autograd::grad({(composed * weights).sum()}, {left, right});
    for (size_t i = 0; i < 2; ++i)
      EXPECT_LT(max_abs_difference(fast_grads[i], composed_grads[i]),
                bound * std::max(1.0, composed_grads[i].abs().max().item<double>()))
          << label << (i == 0 ? ": left" : ": right") << " pose gradient";
    // The avatar's own rotations of the same pose give the same residual as the hand poses alone.
    const at::Tensor joints = at::zeros({body::kSmplxJointCount, 3});
    joints.narrow(0, body::smplx_hand_joint(body::Side::kLeft, 1), 15).copy_(left.detach());
    joints.narrow(0, body::smplx_hand_joint(body::Side::kRight, 1), 15).copy_(right.detach());
    const at::Tensor rotations = body::axis_angle_to_matrix(joints);
    EXPECT_LT(max_abs_difference(hands.forward(left, right, rotations), fast), 1e-7) << label;
  }
  // One hand only: the other's vertices stay zero in both.
  const at::Tensor left = at::rand({15, 3});
  EXPECT_LT(max_abs_difference(hands.forward(left, {}), hands.reference(left, {})), bound) << label;
}

TEST(AvatarHands, LinearMapIsMANOComposedOnTheProceduralBody) {
  expect_linear_map_is_the_composition(procedural_avatar_body(), "procedural");
}

TEST(AvatarHands, LinearMapIsMANOComposedOnTheAnnyStandIns) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  const std::string dir = shared_bodies_folder();
  expect_linear_map_is_the_composition(
      AvatarBody::load(dir + "/anny_smplx_layout.npz", dir + "/anny_mano_left.npz", dir + "/anny_mano_right.npz",
                       dir + "/MANO_SMPLX_vertex_ids.npz", dir + "/FLAME_SMPLX_vertex_ids.npy"),
      "Anny");
}

TEST(AvatarHands, AnnyStandInsGiveASmallHandResidual) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  const std::string dir = shared_bodies_folder();
  const AvatarBody anny =
      AvatarBody::load(dir + "/anny_smplx_layout.npz", dir + "/anny_mano_left.npz", dir + "/anny_mano_right.npz",
                       dir + "/MANO_SMPLX_vertex_ids.npz", dir + "/FLAME_SMPLX_vertex_ids.npy");
  Avatar avatar(anny, subject_betas(), small_config());
  const AvatarOutput out = avatar->forward(test_pose(35, 0.5, true), kTestTime);
  EXPECT_TRUE(at::isfinite(out.means).all().item<bool>());
  // MANO's shape space fitted to the subject's hand leaves millimetres; the residual stays on the hands.
  const double residual = out.hand_residual.abs().max().item<double>();
  EXPECT_LT(residual, 5e-3);
  const at::Tensor hands = avatar->part_labels().ge(static_cast<int64_t>(body::BodyPart::kLeftHand));
  EXPECT_EQ(out.hand_residual.index_select(0, hands.logical_not().nonzero().flatten()).abs().max().item<double>(), 0.0);
  EXPECT_LT(max_abs_difference(out.means, out.posed_vertices), residual + 1e-5);
}

}  // namespace
}  // namespace sfgs::testing
