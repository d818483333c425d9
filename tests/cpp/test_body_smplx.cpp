// The SMPL-X layer (csrc/body/smplx.h) on the procedural body, on a tiny random SMPL-X-layout model (which has pose
// correctives) and on the CC0 Anny stand-in in the official v1.1 layout.
#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "body/mesh.h"
#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/smplx.h"
#include "io/npz.h"
#include "test_body_utils.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

using body::Smplx;
using body::SmplxInput;
using body::SmplxModelData;
using body::SmplxOptions;

SmplxOptions double_options(int64_t betas, int64_t expression, bool pca, bool flat_hand_mean, int64_t levels = 0) {
  SmplxOptions o;
  o.num_betas = betas;
  o.num_expression_coeffs = expression;
  o.use_pca = pca;
  o.num_pca_comps = 6;
  o.flat_hand_mean = flat_hand_mean;
  o.subdivision_levels = levels;
  o.dtype = at::kDouble;
  return o;
}

// An octahedron in the SMPL-X layout with random weights, regressor, blend shapes and pose correctives: every code
// path of the layer at a size where finite differences and full subdivision are cheap.
SmplxModelData tiny_model() {
  at::manual_seed(7);
  SmplxModelData d;
  d.source = "tiny model";
  d.v_template = at::tensor({1.0, 0., 0., -1., 0., 0., 0., 1., 0., 0., -1., 0., 0., 0., 1., 0., 0., -1.}, at::kDouble)
                     .view({6, 3});
  d.faces =
      at::tensor({0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5}, at::kLong).view({8, 3});
  d.weights = at::rand({6, body::kSmplxJointCount}, at::kDouble).pow(4);
  d.weights /= d.weights.sum(1, true);
  d.j_regressor = at::rand({body::kSmplxJointCount, 6}, at::kDouble);
  d.j_regressor /= d.j_regressor.sum(1, true);
  d.parents.assign(body::kSmplxParents.begin(), body::kSmplxParents.end());
  d.shapedirs = 0.1 * at::randn({6, 3, 10}, at::kDouble);
  d.exprdirs = 0.1 * at::randn({6, 3, 10}, at::kDouble);
  d.posedirs = 0.05 * at::randn({6, 3, 486}, at::kDouble);
  d.hands_components_left = std::get<0>(at::linalg_qr(at::randn({45, 45}, at::kDouble)));
  d.hands_components_right = std::get<0>(at::linalg_qr(at::randn({45, 45}, at::kDouble)));
  d.hands_mean_left = 0.1 * at::randn({45}, at::kDouble);
  d.hands_mean_right = 0.1 * at::randn({45}, at::kDouble);
  return d;
}

SmplxInput random_input(int64_t batch, int64_t betas, int64_t expression, int64_t hand_size, double scale,
                        uint64_t seed) {
  at::manual_seed(seed);
  const auto r = [&](std::vector<int64_t> shape) { return scale * at::randn(shape, at::kDouble); };
  SmplxInput in;
  in.betas = r({batch, betas});
  in.pose.global_orient = r({batch, 3});
  in.pose.body_pose = r({batch, 63});
  in.pose.jaw_pose = r({batch, 3});
  in.pose.leye_pose = r({batch, 3});
  in.pose.reye_pose = r({batch, 3});
  in.pose.left_hand_pose = r({batch, hand_size});
  in.pose.right_hand_pose = r({batch, hand_size});
  in.pose.expression = r({batch, expression});
  in.pose.transl = r({batch, 3});
  return in;
}

void expect_template_at_rest(const SmplxModelData& data, bool flat_hand_mean) {
  const Smplx model(data, double_options(10, 10, true, flat_hand_mean));
  const auto out = model->forward(SmplxInput{});
  EXPECT_LT(max_difference(out.vertices[0], data.v_template), 1e-12);
  EXPECT_LT(max_difference(out.joints[0], data.j_regressor.matmul(data.v_template)), 1e-12);
  EXPECT_LT(max_difference(out.skinning_transforms, at::eye(4, at::kDouble).expand({1, 55, 4, 4})), 1e-12);
  EXPECT_LT(max_difference(out.joint_transforms.narrow(2, 0, 3).narrow(3, 0, 3),
                           at::eye(3, at::kDouble).expand({1, 55, 3, 3})),
            1e-12);
  EXPECT_LT(max_difference(out.joint_transforms.select(3, 3).narrow(2, 0, 3), out.joints), 1e-12);
}

TEST(BodySmplx, ZeroPoseAndShapeGiveTheTemplate) {
  expect_template_at_rest(procedural_body().smplx, /*flat_hand_mean=*/true);
  expect_template_at_rest(tiny_model(), true);
  // Without flat_hand_mean the procedural body's relaxed mean curls the fingers and moves nothing else.
  const auto& data = procedural_body().smplx;
  const auto out = Smplx(data, double_options(10, 10, true, false))->forward(SmplxInput{});
  EXPECT_LT(max_difference(out.full_pose[0].narrow(0, 25, 15).flatten(), data.hands_mean_left), 1e-15);
  const at::Tensor moved = ((out.vertices[0] - data.v_template).norm(2, 1) > 1e-9);
  const at::Tensor in_hands = (data.part_labels == 2) | (data.part_labels == 3);
  EXPECT_GT(moved.sum().item<int64_t>(), 1000);
  EXPECT_TRUE(moved.logical_and(in_hands.logical_not()).sum().item<int64_t>() < moved.sum().item<int64_t>() / 20);
}

TEST(BodySmplx, AnnyZeroPoseGivesTheTemplate) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  expect_template_at_rest(anny_smplx(), false);  // Anny's hand mean is zero
}

TEST(BodySmplx, JointsAreTheRegressorAppliedToTheShapedMesh) {
  for (const SmplxModelData& d : {procedural_body().smplx, tiny_model()}) {
    const int64_t e = std::min<int64_t>(8, d.exprdirs.size(2));
    const Smplx model(d, double_options(10, e, false, true));
    SmplxInput in = random_input(3, 10, e, 45, 0.3, 11);
    const auto out = model->forward(in);
    const at::Tensor shaped = d.v_template + at::einsum("vck,bk->bvc", {d.shapedirs.narrow(2, 0, 10), in.betas}) +
                              at::einsum("vck,bk->bvc", {d.exprdirs.narrow(2, 0, e), in.pose.expression});
    EXPECT_LT(max_difference(out.rest_joints, at::einsum("jv,bvc->bjc", {d.j_regressor, shaped})), 1e-12);
    if (!d.posedirs.defined()) EXPECT_LT(max_difference(out.rest_vertices, shaped), 1e-12);
    // Unposed, the output joints are the regressor on the output mesh, moved by the translation.
    SmplxInput rest;
    rest.betas = in.betas;
    rest.pose.expression = in.pose.expression;
    rest.pose.transl = in.pose.transl;
    const auto still = model->forward(rest);
    EXPECT_LT(max_difference(still.joints, at::einsum("jv,bvc->bjc", {d.j_regressor, still.vertices})), 1e-12);
    EXPECT_LT(max_difference(still.vertices - in.pose.transl.unsqueeze(1), shaped), 1e-12);
  }
}

TEST(BodySmplx, PoseCorrectivesAreTheFeatureTimesPosedirs) {
  const SmplxModelData d = tiny_model();
  const Smplx model(d, double_options(10, 10, false, true));
  const SmplxInput in = random_input(2, 10, 10, 45, 0.4, 12);
  const auto out = model->forward(in);
  const at::Tensor feature = (out.rotations.narrow(1, 1, 54) - at::eye(3, at::kDouble)).flatten(1);
  const at::Tensor shaped = d.v_template + at::einsum("vck,bk->bvc", {d.shapedirs, in.betas}) +
                            at::einsum("vck,bk->bvc", {d.exprdirs, in.pose.expression});
  EXPECT_LT(max_difference(out.rest_vertices, shaped + at::einsum("vcp,bp->bvc", {d.posedirs, feature})), 1e-12);
  // And the posed vertices are the blended transforms applied to that rest mesh.
  const at::Tensor blended = at::einsum("vj,bjrc->bvrc", {d.weights, out.skinning_transforms});
  const at::Tensor homogeneous = at::cat({out.rest_vertices, at::ones({2, 6, 1}, at::kDouble)}, 2);
  EXPECT_LT(max_difference(out.vertices, at::einsum("bvrc,bvc->bvr", {blended, homogeneous}).narrow(2, 0, 3)), 1e-12);
}

TEST(BodySmplx, SparseAndDenseSkinningWeightsAgree) {
  at::manual_seed(8);
  const at::Tensor weights = at::rand({50, 55}, at::kDouble) * (at::rand({50, 55}, at::kDouble) < 0.1);
  const at::Tensor rest = at::randn({3, 50, 3}, at::kDouble);
  const at::Tensor transforms = at::randn({3, 55, 4, 4}, at::kDouble).requires_grad_(true);
  const at::Tensor dense = body::linear_blend_skinning(rest, weights, transforms);
  const at::Tensor sparse = body::linear_blend_skinning(rest, body::sparse_skinning_weights(weights), transforms);
  EXPECT_LT(max_difference(dense, sparse), 1e-13);
  const at::Tensor w = at::randn_like(dense);
  const at::Tensor g_dense = torch::autograd::grad({(dense * w).sum()}, {transforms})[0];
  const at::Tensor g_sparse = torch::autograd::grad({(sparse * w).sum()}, {transforms})[0];
  EXPECT_LT(max_difference(g_dense, g_sparse), 1e-13);
  // By hand for one vertex: sum_j w_j A_j [v; 1].
  const at::Tensor blended = at::einsum("j,jrc->rc", {weights[7], transforms.detach()[1]});
  EXPECT_LT(max_difference(dense[1][7], blended.narrow(0, 0, 3).narrow(1, 0, 3).matmul(rest[1][7]) +
                                            blended.narrow(0, 0, 3).select(1, 3)),
            1e-13);
}

// Poses joint j alone (axis-angle `rotation`) and checks that only its subtree moves, rigidly about the joint.
void expect_subtree_moves_rigidly(const SmplxModelData& d, int64_t j, const at::Tensor& rotation) {
  const Smplx model(d, double_options(10, 0, false, true));
  SmplxInput rest;
  rest.betas = 0.5 * at::randn({1, 10}, at::kDouble);
  SmplxInput posed = rest;
  at::Tensor full = at::zeros({1, 55, 3}, at::kDouble);
  full[0][j] = rotation;
  posed.pose.global_orient = full.select(1, 0);
  posed.pose.body_pose = full.narrow(1, 1, 21).flatten(1);
  posed.pose.jaw_pose = full.select(1, 22);
  posed.pose.leye_pose = full.select(1, 23);
  posed.pose.reye_pose = full.select(1, 24);
  posed.pose.left_hand_pose = full.narrow(1, 25, 15).flatten(1);
  posed.pose.right_hand_pose = full.narrow(1, 40, 15).flatten(1);
  const auto a = model->forward(rest), b = model->forward(posed);
  const at::Tensor r = body::axis_angle_to_matrix(rotation);
  const at::Tensor centre = a.joints[0][j];
  const auto rigid = [&](const at::Tensor& p) { return (p - centre).matmul(r.t()) + centre; };
  std::vector<int64_t> subtree, others;
  for (int64_t k = 0; k < 55; ++k) (model->mesh()->tree()->in_subtree(j, k) ? subtree : others).push_back(k);
  const at::Tensor in = at::tensor(subtree, at::kLong), out = at::tensor(others, at::kLong);
  if (!others.empty())
    EXPECT_LT(max_difference(b.joints[0].index_select(0, out), a.joints[0].index_select(0, out)), 1e-12);
  EXPECT_LT(max_difference(b.joints[0].index_select(0, in), rigid(a.joints[0].index_select(0, in))), 1e-12);
  const at::Tensor share = d.weights.index_select(1, in).sum(1);
  const at::Tensor still = (share == 0).nonzero().flatten(), carried = (share > 1 - 1e-12).nonzero().flatten();
  EXPECT_GT(carried.size(0), 0) << "joint " << j;
  if (still.size(0) > 0)
    EXPECT_LT(max_difference(b.vertices[0].index_select(0, still), a.vertices[0].index_select(0, still)), 1e-12);
  EXPECT_LT(max_difference(b.vertices[0].index_select(0, carried), rigid(a.vertices[0].index_select(0, carried))),
            1e-11)
      << "joint " << j;
  const at::Tensor expected_transform = at::eye(4, at::kDouble);
  expected_transform.narrow(0, 0, 3).narrow(1, 0, 3).copy_(r);
  expected_transform.narrow(0, 0, 3).select(1, 3).copy_(centre - r.matmul(centre));
  for (int64_t k : subtree) EXPECT_LT(max_difference(b.skinning_transforms[0][k], expected_transform), 1e-12);
  for (int64_t k : others) EXPECT_LT(max_difference(b.skinning_transforms[0][k], at::eye(4, at::kDouble)), 1e-12);
}

TEST(BodySmplx, RotatingOneJointMovesOnlyItsDescendantsRigidly) {
  at::manual_seed(3);
  for (int64_t j : {0, 5, 9, 15, 18, 20, 23, 26, 37, 52}) {
    expect_subtree_moves_rigidly(procedural_body().smplx, j, at::tensor({0.4, -0.7, 0.3}, at::kDouble));
  }
}

TEST(BodySmplx, AnnyRotatingOneJointMovesOnlyItsDescendantsRigidly) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  for (int64_t j : {4, 15, 16, 21, 44})
    expect_subtree_moves_rigidly(anny_smplx(), j, at::tensor({-0.5, 0.2, 0.6}, at::kDouble));
}

TEST(BodySmplx, HandPcaIsTheComponentsTimesTheCoefficientsPlusTheMean) {
  const auto& d = procedural_body().smplx;
  const Smplx pca(d, double_options(10, 8, true, false));
  const Smplx full(d, double_options(10, 8, false, false));
  const SmplxInput in = random_input(2, 10, 8, 6, 0.5, 21);
  SmplxInput as_full = in;
  as_full.pose.left_hand_pose = in.pose.left_hand_pose.matmul(d.hands_components_left.narrow(0, 0, 6));
  as_full.pose.right_hand_pose = in.pose.right_hand_pose.matmul(d.hands_components_right.narrow(0, 0, 6));
  const auto a = pca->forward(in), b = full->forward(as_full);
  EXPECT_LT(max_difference(a.vertices, b.vertices), 1e-12);
  EXPECT_LT(max_difference(a.full_pose.narrow(1, 25, 15).flatten(1), as_full.pose.left_hand_pose + d.hands_mean_left),
            1e-14);
}

TEST(BodySmplx, AnnyHandPcaWithIdentityComponentsEqualsTheFullPose) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  SmplxOptions options = double_options(10, 10, true, false);
  options.num_pca_comps = 45;
  const Smplx pca(anny_smplx(), options);
  const Smplx full(anny_smplx(), double_options(10, 10, false, false));
  const SmplxInput in = random_input(2, 10, 10, 45, 0.4, 22);
  EXPECT_LT(max_difference(pca->forward(in).vertices, full->forward(in).vertices), 1e-12);
  // Six components: the first six axis-angle values of each hand.
  const Smplx six(anny_smplx(), double_options(10, 10, true, false));
  SmplxInput few = random_input(2, 10, 10, 6, 0.4, 23), padded = few;
  padded.pose.left_hand_pose = at::cat({few.pose.left_hand_pose, at::zeros({2, 39}, at::kDouble)}, 1);
  padded.pose.right_hand_pose = at::cat({few.pose.right_hand_pose, at::zeros({2, 39}, at::kDouble)}, 1);
  EXPECT_LT(max_difference(six->forward(few).vertices, full->forward(padded).vertices), 1e-12);
}

TEST(BodySmplx, RotationMatricesCanReplaceTheAxisAngles) {
  const auto& d = procedural_body().smplx;
  const Smplx model(d, double_options(10, 8, true, false));
  const SmplxInput in = random_input(2, 10, 8, 6, 0.5, 31);
  const auto a = model->forward(in);
  SmplxInput by_matrix;
  by_matrix.betas = in.betas;
  by_matrix.pose.expression = in.pose.expression;
  by_matrix.pose.transl = in.pose.transl;
  by_matrix.rotations = body::rotation_6d_to_matrix(body::matrix_to_rotation_6d(a.rotations));
  const auto b = model->forward(by_matrix);
  EXPECT_LT(max_difference(a.vertices, b.vertices), 1e-12);
  EXPECT_FALSE(b.full_pose.defined());
  SmplxInput both = by_matrix;
  both.pose.jaw_pose = in.pose.jaw_pose;
  expect_error([&] { model->forward(both); }, {"either rotations or axis-angle poses", "jaw_pose"});
}

TEST(BodySmplx, OffsetsMoveTheTemplateAndTheJoints) {
  const auto& d = procedural_body().smplx;
  const Smplx model(d, double_options(10, 8, true, true));
  SmplxInput in;
  in.vertex_offsets = 0.01 * at::randn({d.v_template.size(0), 3}, at::kDouble);
  in.joint_offsets = 0.01 * at::randn({2, 55, 3}, at::kDouble);
  const auto out = model->forward(in);
  EXPECT_LT(max_difference(out.vertices[1], d.v_template + in.vertex_offsets), 1e-12);
  EXPECT_LT(max_difference(out.joints, d.j_regressor.matmul(d.v_template + in.vertex_offsets) + in.joint_offsets),
            1e-12);
}

TEST(BodySmplx, ConvertingAModuleLeavesTheModelDataAndOtherModulesAlone) {
  const SmplxModelData d = tiny_model();
  Smplx converted(d, double_options(10, 10, true, false, 1));
  const Smplx untouched(d, double_options(10, 10, true, false, 1));
  converted->to(at::kFloat);
  EXPECT_EQ(converted->dtype(), at::kFloat);
  EXPECT_EQ(untouched->dtype(), at::kDouble);
  for (const at::Tensor* t : {&d.v_template, &d.j_regressor, &d.weights, &d.posedirs, &d.hands_mean_left})
    EXPECT_EQ(t->scalar_type(), at::kDouble);
  SmplxInput in = random_input(2, 10, 10, 6, 0.3, 45), as_float;
  for (const auto& [source, target] :
       std::vector<std::pair<const at::Tensor*, at::Tensor*>>{{&in.betas, &as_float.betas},
                                                              {&in.pose.body_pose, &as_float.pose.body_pose},
                                                              {&in.pose.left_hand_pose, &as_float.pose.left_hand_pose},
                                                              {&in.pose.expression, &as_float.pose.expression}}) {
    *target = source->to(at::kFloat);
  }
  in.pose.global_orient = in.pose.jaw_pose = in.pose.leye_pose = in.pose.reye_pose = in.pose.right_hand_pose =
      in.pose.transl = at::Tensor();
  EXPECT_LT(max_difference(converted->forward(as_float).vertices.to(at::kDouble), untouched->forward(in).vertices),
            1e-5);
}

TEST(BodySmplx, BatchesAreIndependent) {
  const Smplx model(procedural_body().smplx, double_options(10, 8, true, false));
  const SmplxInput in = random_input(3, 10, 8, 6, 0.5, 41);
  const auto all = model->forward(in);
  for (int64_t b = 0; b < 3; ++b) {
    SmplxInput one;
    for (const auto& [source, target] :
         std::vector<std::pair<const at::Tensor*, at::Tensor*>>{{&in.betas, &one.betas},
                                                                {&in.pose.global_orient, &one.pose.global_orient},
                                                                {&in.pose.body_pose, &one.pose.body_pose},
                                                                {&in.pose.jaw_pose, &one.pose.jaw_pose},
                                                                {&in.pose.leye_pose, &one.pose.leye_pose},
                                                                {&in.pose.reye_pose, &one.pose.reye_pose},
                                                                {&in.pose.left_hand_pose, &one.pose.left_hand_pose},
                                                                {&in.pose.right_hand_pose, &one.pose.right_hand_pose},
                                                                {&in.pose.expression, &one.pose.expression},
                                                                {&in.pose.transl, &one.pose.transl}})
      *target = source->narrow(0, b, 1);
    EXPECT_LT(max_difference(model->forward(one).vertices[0], all.vertices[b]), 1e-12);
  }
}

TEST(BodySmplx, TheSubdividedLayerEqualsTheLayerOfTheSubdividedModel) {
  for (const bool tiny : {true, false}) {
    const SmplxModelData d = tiny ? tiny_model() : procedural_body().smplx;
    const int64_t levels = tiny ? 2 : 1;
    const int64_t e = tiny ? 10 : 8;
    const Smplx on_the_fly(d, double_options(10, e, true, false, levels));
    const Smplx precomputed(body::subdivide(d, levels), double_options(10, e, true, false));
    const SmplxInput in = random_input(2, 10, e, 6, 0.4, 51);
    const auto a = on_the_fly->forward(in), b = precomputed->forward(in);
    EXPECT_EQ(on_the_fly->vertex_count(), precomputed->vertex_count());
    EXPECT_LT(max_difference(a.vertices, b.vertices), 1e-12);
    EXPECT_LT(max_difference(a.joints, b.joints), 1e-12);
    EXPECT_TRUE(on_the_fly->faces().equal(precomputed->faces()));
    if (!tiny) {
      EXPECT_TRUE(on_the_fly->uvs().equal(body::subdivide(d, levels).uvs));
      EXPECT_TRUE(on_the_fly->part_labels().equal(body::subdivide(d, levels).part_labels));
    }
  }
}

TEST(BodySmplx, GradientsReachEveryInputAndMatchFiniteDifferences) {
  const SmplxModelData d = tiny_model();
  const Smplx model(d, double_options(10, 10, true, false, /*levels=*/1));
  at::manual_seed(61);
  SmplxInput in = random_input(2, 10, 10, 6, 0.4, 62);
  in.vertex_offsets = 0.05 * at::randn({2, 6, 3}, at::kDouble);
  in.joint_offsets = 0.05 * at::randn({2, 55, 3}, at::kDouble);
  const std::vector<std::pair<const char*, at::Tensor*>> inputs = {{"betas", &in.betas},
                                                                   {"global_orient", &in.pose.global_orient},
                                                                   {"body_pose", &in.pose.body_pose},
                                                                   {"jaw_pose", &in.pose.jaw_pose},
                                                                   {"leye_pose", &in.pose.leye_pose},
                                                                   {"reye_pose", &in.pose.reye_pose},
                                                                   {"left_hand_pose", &in.pose.left_hand_pose},
                                                                   {"right_hand_pose", &in.pose.right_hand_pose},
                                                                   {"expression", &in.pose.expression},
                                                                   {"transl", &in.pose.transl},
                                                                   {"vertex_offsets", &in.vertex_offsets},
                                                                   {"joint_offsets", &in.joint_offsets}};
  const at::Tensor wv = at::randn({2, model->vertex_count(), 3}, at::kDouble), wj = at::randn({2, 55, 3}, at::kDouble);
  const at::Tensor wt = at::randn({2, 55, 4, 4}, at::kDouble);
  const auto loss = [&] {
    const auto out = model->forward(in);
    return (out.vertices * wv).sum() + (out.joints * wj).sum() + (out.skinning_transforms * wt).sum() +
           (out.joint_transforms * wt).sum();
  };
  for (auto& [name, t] : inputs) t->requires_grad_(true);
  loss().backward();
  for (auto& [name, t] : inputs) {
    const at::Tensor grad = t->grad();
    ASSERT_TRUE(grad.defined()) << name;
    EXPECT_GT(grad.abs().sum().item<double>(), 1e-6) << name;
    const at::Tensor values = t->detach();
    for (int64_t k : {int64_t{0}, values.numel() / 2, values.numel() - 1}) {
      const double fd = central_difference([&] { return loss().item<double>(); }, values, k, 1e-6);
      const double g = grad.flatten()[k].item<double>();
      EXPECT_NEAR(g, fd, 1e-6 * std::max(1.0, std::abs(fd))) << name << "[" << k << "]";
    }
  }
}

TEST(BodySmplx, InputsAreCheckedWithClearMessages) {
  const Smplx model(procedural_body().smplx, double_options(10, 8, true, false));
  const auto run = [&](const std::function<void(SmplxInput&)>& spoil) {
    SmplxInput in = random_input(2, 10, 8, 6, 0.1, 71);
    spoil(in);
    model->forward(in);
  };
  expect_error([&] { run([](SmplxInput& in) {
                       in.pose.body_pose = at::zeros({2, 60}, at::kDouble);
                     }); },
               {"body_pose", "shape [2, 63]", "got a Double tensor of shape [2, 60]"});
  expect_error([&] { run([](SmplxInput& in) {
                       in.betas = at::zeros({3, 10}, at::kDouble);
                     }); },
               {"disagree on the batch size", "betas has 3", "global_orient has 2"});
  expect_error([&] { run([](SmplxInput& in) { in.pose.transl = in.pose.transl.to(at::kFloat); }); },
               {"transl must be a Double tensor", "got a Float tensor"});
  expect_error([&] { run([](SmplxInput& in) {
                       in.pose.left_hand_pose = at::zeros({2, 45}, at::kDouble);
                     }); },
               {"left_hand_pose (PCA coefficients)", "[2, 6]"});
  expect_error([&] { run([](SmplxInput& in) {
                       in.vertex_offsets = at::zeros({2, 10, 3}, at::kDouble);
                     }); },
               {"vertex_offsets"});
  SmplxOptions too_many = double_options(10, 8, true, false);
  too_many.num_pca_comps = 46;
  expect_error([&] { Smplx(procedural_body().smplx, too_many); }, {"num_pca_comps must lie in [1, 45]"});
  // (B, 21, 3) poses are as good as (B, 63).
  SmplxInput in = random_input(2, 10, 8, 6, 0.3, 72), shaped = in;
  shaped.pose.body_pose = in.pose.body_pose.view({2, 21, 3});
  EXPECT_TRUE(model->forward(in).vertices.equal(model->forward(shaped).vertices));
}

TEST(BodySmplx, SavedModelsLoadBackAndEvaluateIdentically) {
  ScratchFolder folder;
  SmplxModelData d = tiny_model();
  d.uvs = at::rand({8, 2}, at::kDouble);
  d.uv_faces = at::randint(0, 8, {8, 3}, at::kLong);
  d.part_labels = at::tensor({0, 1, 2, 3, 0, 1}, at::kInt).to(at::kByte);
  d.posedirs = at::Tensor();
  d.save(folder.file("body.npz"), false);
  const SmplxModelData back = SmplxModelData::load(folder.file("body.npz"));
  EXPECT_TRUE(back.v_template.equal(d.v_template));
  EXPECT_TRUE(back.faces.equal(d.faces));
  EXPECT_TRUE(back.weights.equal(d.weights));
  EXPECT_TRUE(back.j_regressor.equal(d.j_regressor));
  EXPECT_EQ(back.parents, d.parents);
  EXPECT_EQ(back.shapedirs.size(2), 300);  // written in the v1.1 layout
  EXPECT_EQ(back.exprdirs.size(2), 100);
  EXPECT_TRUE(back.shapedirs.narrow(2, 0, 10).equal(d.shapedirs));
  EXPECT_TRUE(back.exprdirs.narrow(2, 0, 10).equal(d.exprdirs));
  EXPECT_EQ(back.shapedirs.narrow(2, 10, 290).abs().max().item<double>(), 0.0);
  EXPECT_FALSE(back.posedirs.defined());  // all-zero correctives are dropped
  EXPECT_TRUE(back.uvs.equal(d.uvs) && back.uv_faces.equal(d.uv_faces) && back.part_labels.equal(d.part_labels));
  EXPECT_TRUE(back.hands_components_left.equal(d.hands_components_left) &&
              back.hands_mean_right.equal(d.hands_mean_right));
  const io::NpzArchive npz(folder.file("body.npz"));
  EXPECT_EQ(npz.read("kintree_table")[0][0].item<int64_t>(), 4294967295LL);  // the official root marker
  EXPECT_EQ(npz.read("posedirs").sizes(), (std::vector<int64_t>{6, 3, 486}));
  const SmplxInput in = random_input(1, 10, 10, 6, 0.4, 81);
  const Smplx a(d, double_options(10, 10, true, false));
  const Smplx b(folder.file("body.npz"), double_options(10, 10, true, false));
  EXPECT_TRUE(a->forward(in).vertices.equal(b->forward(in).vertices));
  // Pose correctives survive the round trip too.
  const SmplxModelData with_correctives = tiny_model();
  with_correctives.save(folder.file("correctives.npz"), false);
  EXPECT_TRUE(SmplxModelData::load(folder.file("correctives.npz")).posedirs.equal(with_correctives.posedirs));
}

TEST(BodySmplx, AnnyLoadsAsAnOfficialV11File) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  const SmplxModelData& d = anny_smplx();
  EXPECT_EQ(d.v_template.sizes(), (std::vector<int64_t>{13492, 3}));
  EXPECT_EQ(d.shapedirs.size(2), 300);
  EXPECT_EQ(d.exprdirs.size(2), 100);
  EXPECT_FALSE(d.posedirs.defined());
  EXPECT_EQ(d.uvs.size(0), 14645);
  EXPECT_EQ(d.parents, std::vector<int64_t>(body::kSmplxParents.begin(), body::kSmplxParents.end()));
  // ExAvatar's configuration: 100 betas, 50 expression coefficients, full hand poses.
  SmplxOptions options = double_options(100, 50, false, false);
  const Smplx model(d, options);
  EXPECT_EQ(model->options().num_betas, 100);
  const auto out = model->forward(random_input(2, 100, 50, 45, 0.2, 91));
  EXPECT_TRUE(at::isfinite(out.vertices).all().item<bool>());
  // Asking for more than the file has is clamped, not an error.
  options.num_betas = 400;
  EXPECT_EQ(Smplx(d, options)->options().num_betas, 300);
}

// Writes the tiny model's arrays with one of them replaced (or removed when `replacement` is undefined).
std::string spoiled_file(const ScratchFolder& folder, const std::string& key, const at::Tensor& replacement) {
  const std::string clean = folder.file("clean.npz");
  if (!std::filesystem::exists(clean)) tiny_model().save(clean, false);
  const io::NpzArchive npz(clean);
  std::vector<std::pair<std::string, at::Tensor>> arrays;
  for (const std::string& k : npz.keys()) {
    if (k != key)
      arrays.emplace_back(k, npz.read(k));
    else if (replacement.defined())
      arrays.emplace_back(k, replacement);
  }
  const std::string path = folder.file("spoiled_" + key + ".npz");
  io::write_npz(path, arrays, true);
  return path;
}

TEST(BodySmplx, BadModelFilesAreClearErrors) {
  ScratchFolder folder;
  const auto load = [](const std::string& path) { SmplxModelData::load(path); };
  expect_error([&] { load(spoiled_file(folder, "weights", {})); },
               {"spoiled_weights.npz", "is not an SMPL-X model file", "no array 'weights'"});
  expect_error(
      [&] {
        load(spoiled_file(folder, "J_regressor", at::zeros({24, 6}, at::kDouble)));
      },
      {"'J_regressor' of", "regresses 24 joints; SMPL-X has 55", "SMPL file has 24"});
  expect_error(
      [&] {
        load(spoiled_file(folder, "shapedirs", at::zeros({6, 3, 7}, at::kDouble)));
      },
      {"has 7 blend shapes", "v1.1 has 400"});
  expect_error(
      [&] {
        load(spoiled_file(folder, "f", at::tensor({0, 1, 9}, at::kLong).view({1, 3})));
      },
      {"'f' of", "index vertices 0..9, but there are 6"});
  expect_error(
      [&] {
        load(spoiled_file(folder, "v_template", at::full({6, 3}, NAN, at::kDouble)));
      },
      {"v_template holds NaN"});
  expect_error(
      [&] {
        load(spoiled_file(folder, "weights", at::zeros({6, 55}, at::kInt)));
      },
      {"'weights' of", "must be a floating array of shape (6, 55)", "Int"});
  at::Tensor bad_tree = io::NpzArchive(folder.file("clean.npz")).read("kintree_table").clone();
  bad_tree[0][5] = 30;
  expect_error([&] { load(spoiled_file(folder, "kintree_table", bad_tree)); },
               {"the parent of joint 5 must be an earlier joint, got 30"});
  expect_error([&] { load(folder.file("SMPLX_NEUTRAL.npz")); }, {"SMPLX_NEUTRAL.npz", "does not exist"});
  // v1.0 files carry 10 shape + 10 expression directions.
  const at::Tensor v10 = at::randn({6, 3, 20}, at::kDouble);
  const SmplxModelData old = SmplxModelData::load(spoiled_file(folder, "shapedirs", v10));
  EXPECT_TRUE(old.shapedirs.equal(v10.narrow(2, 0, 10)) && old.exprdirs.equal(v10.narrow(2, 10, 10)));
  EXPECT_EQ(Smplx(old, double_options(10, 50, true, false))->options().num_expression_coeffs, 10);
}

}  // namespace
}  // namespace sfgs::testing
