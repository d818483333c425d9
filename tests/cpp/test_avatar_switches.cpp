// The avatar's ablation switches: each removes exactly its module. An ablated avatar gets the full avatar's
// parameters (by name), so every difference between the two is the switched module's doing.
#include <string>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <gtest/gtest.h>

#include "body/parts.h"
#include "model/avatar.h"
#include "test_avatar_utils.h"

namespace sfgs::testing {
namespace {

using model::Avatar;
using model::AvatarConfig;
using model::AvatarOutput;

constexpr double kTolerance = 1e-6;

struct Pair {
  Avatar full{nullptr}, ablated{nullptr};
};

// A full avatar with random parameters, and one with `ablate` applied to its config sharing them.
template <typename Ablate> Pair full_and_ablated(const Ablate& ablate) {
  Pair p;
  p.full = Avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*p.full, 0.1, 21);
  AvatarConfig config = small_config();
  ablate(config);
  p.ablated = Avatar(procedural_avatar_body(), subject_betas(), config);
  copy_parameters(*p.full, *p.ablated);
  return p;
}

bool has_parameter_containing(const Avatar& avatar, const std::string& part) {
  for (const auto& p : avatar->named_parameters())
    if (p.key().find(part) != std::string::npos) return true;
  return false;
}

at::Tensor rows(const at::Tensor& t, const at::Tensor& mask) { return t.index_select(0, mask.nonzero().flatten()); }

TEST(AvatarSwitches, WithoutHexplaneNothingDependsOnTime) {
  Pair p = full_and_ablated([](AvatarConfig& c) { c.use_hexplane = false; });
  EXPECT_FALSE(has_parameter_containing(p.ablated, "hexplane"));
  EXPECT_FALSE(has_parameter_containing(p.ablated, "gate"));
  const AvatarOutput early = p.ablated->forward(test_pose(1, 0.4, true), -0.6);
  const AvatarOutput late = p.ablated->forward(test_pose(1, 0.4, true), 0.8);
  EXPECT_TRUE(early.means.equal(late.means));
  EXPECT_TRUE(early.covariances.equal(late.covariances));
  EXPECT_TRUE(early.colours.equal(late.colours));
  // With it, the canonical attributes move with time.
  const AvatarOutput full_early = p.full->forward(test_pose(1, 0.4, true), -0.6);
  const AvatarOutput full_late = p.full->forward(test_pose(1, 0.4, true), 0.8);
  EXPECT_GT(max_abs_difference(full_early.mean_offset, full_late.mean_offset), 1e-4);
  EXPECT_GT(max_abs_difference(full_early.colours, full_late.colours), 1e-4);
}

TEST(AvatarSwitches, WithoutStructureOffsetOnlyItsOffsetsGo) {
  Pair p = full_and_ablated([](AvatarConfig& c) { c.use_structure_offset = false; });
  EXPECT_FALSE(has_parameter_containing(p.ablated, "structure"));
  const body::SmplxPose pose = test_pose(2, 0.4, true);
  const AvatarOutput full = p.full->forward(pose, kTestTime), ablated = p.ablated->forward(pose, kTestTime);
  // A switched-off module costs nothing: its outputs are not even allocated.
  EXPECT_FALSE(ablated.structure_offset.defined());
  EXPECT_FALSE(ablated.scale_offset.defined());
  EXPECT_GT(full.structure_offset.abs().max().item<double>(), 1e-4);
  EXPECT_LT(max_abs_difference(full.mean_offset, ablated.mean_offset), kTolerance);
  EXPECT_LT(max_abs_difference(full.colours, ablated.colours), kTolerance);
  EXPECT_LT(max_abs_difference(full.hand_residual, ablated.hand_residual), kTolerance);
  EXPECT_LT(max_abs_difference(full.canonical_means - ablated.canonical_means, full.structure_offset), kTolerance);
  EXPECT_LT(max_abs_difference(full.log_scales - ablated.log_scales, full.scale_offset), kTolerance);
  // The structure offset is what follows the pose; the canonical head's offset does not.
  const AvatarOutput other = p.full->forward(test_pose(3, 0.4, true), kTestTime);
  EXPECT_GT(max_abs_difference(full.structure_offset, other.structure_offset), 1e-4);
  EXPECT_TRUE(full.mean_offset.equal(other.mean_offset));
}

TEST(AvatarSwitches, WithoutColourOffsetColoursDoNotDependOnPose) {
  Pair p = full_and_ablated([](AvatarConfig& c) { c.use_colour_offset = false; });
  EXPECT_FALSE(has_parameter_containing(p.ablated, "colour_offset"));
  const body::SmplxPose a = test_pose(4, 0.4, true), b = test_pose(5, 0.4, true);
  const AvatarOutput ablated_a = p.ablated->forward(a, kTestTime), ablated_b = p.ablated->forward(b, kTestTime);
  // Only the light of the posed normals changes (shading.h): the shading-free colours are the same,
  // c_a / s_a = c_b / s_b, compared without dividing.
  EXPECT_LT(max_abs_difference(ablated_a.colours * ablated_b.shading, ablated_b.colours * ablated_a.shading), 1e-6);
  EXPECT_FALSE(ablated_a.colour_offset.defined());
  const AvatarOutput full_a = p.full->forward(a, kTestTime), full_b = p.full->forward(b, kTestTime);
  EXPECT_GT(max_abs_difference(full_a.colours, full_b.colours), 1e-4);
  EXPECT_LT(max_abs_difference(full_a.means, ablated_a.means), kTolerance);
  EXPECT_LT(max_abs_difference(full_a.covariances, ablated_a.covariances), kTolerance);
}

TEST(AvatarSwitches, WithoutHandResidualOnlyHandPointsChange) {
  Pair p = full_and_ablated([](AvatarConfig& c) { c.use_hand_residual = false; });
  EXPECT_FALSE(has_parameter_containing(p.ablated, "hand_residual"));
  const body::SmplxPose pose = test_pose(6, 0.4, true);
  const AvatarOutput full = p.full->forward(pose, kTestTime), ablated = p.ablated->forward(pose, kTestTime);
  EXPECT_FALSE(ablated.hand_residual.defined());
  EXPECT_LT(max_abs_difference(full.canonical_means - ablated.canonical_means, full.hand_residual), kTolerance);
  // Without subdivision the residual lives on the MANO-corresponding vertices only.
  const auto& ids = procedural_avatar_body().hand_vertex_ids;
  at::Tensor on_hands = at::zeros({p.full->gaussian_count()}, at::kBool);
  on_hands.index_fill_(0, at::cat({ids.left, ids.right}), true);
  EXPECT_EQ(rows(full.hand_residual, on_hands.logical_not()).abs().max().item<double>(), 0.0);
  EXPECT_GT(rows(full.hand_residual, on_hands).abs().max().item<double>(), 1e-4);
  EXPECT_LT(max_abs_difference(rows(full.means, on_hands.logical_not()), rows(ablated.means, on_hands.logical_not())),
            kTolerance);
  EXPECT_LT(max_abs_difference(full.colours, ablated.colours), kTolerance);
}

TEST(AvatarSwitches, HandResidualIsSkippedForHandsWithoutPoses) {
  Pair p = full_and_ablated([](AvatarConfig& c) { c.use_hand_residual = false; });
  body::SmplxPose pose = test_pose(7, 0.4, /*hands=*/false);
  const AvatarOutput no_hands = p.full->forward(pose, kTestTime);
  EXPECT_FALSE(no_hands.hand_residual.defined());
  EXPECT_LT(max_abs_difference(no_hands.means, p.ablated->forward(pose, kTestTime).means), kTolerance);
  // Only the left hand posed: only the left hand gets a residual.
  pose.left_hand_pose = test_pose(8, 0.4, true).left_hand_pose;
  const AvatarOutput left_only = p.full->forward(pose, kTestTime);
  const auto& ids = procedural_avatar_body().hand_vertex_ids;
  EXPECT_GT(left_only.hand_residual.index_select(0, ids.left).abs().max().item<double>(), 1e-4);
  EXPECT_EQ(left_only.hand_residual.index_select(0, ids.right).abs().max().item<double>(), 0.0);
}

TEST(AvatarSwitches, WithoutFacePlanesOnlyFacePointsChange) {
  Pair p = full_and_ablated([](AvatarConfig& c) { c.use_face_planes = false; });
  EXPECT_FALSE(has_parameter_containing(p.ablated, "face"));
  EXPECT_TRUE(has_parameter_containing(p.full, "face_triplane"));
  EXPECT_TRUE(has_parameter_containing(p.full, "face_hexplane"));
  const body::SmplxPose pose = test_pose(9, 0.4, true);
  const AvatarOutput full = p.full->forward(pose, kTestTime), ablated = p.ablated->forward(pose, kTestTime);
  const at::Tensor face = p.full->part_labels().eq(static_cast<int64_t>(body::BodyPart::kFace));
  const at::Tensor elsewhere = face.logical_not();
  for (const auto& [name, a, b] : {std::tuple{"means", full.means, ablated.means},
                                   {"log_scales", full.log_scales, ablated.log_scales},
                                   {"colours", full.colours, ablated.colours}}) {
    EXPECT_LT(max_abs_difference(rows(a, elsewhere), rows(b, elsewhere)), kTolerance) << name;
    EXPECT_GT(max_abs_difference(rows(a, face), rows(b, face)), 1e-4) << name;
  }
}

}  // namespace
}  // namespace sfgs::testing
