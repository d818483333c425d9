// The SFGS avatar (csrc/model/avatar.h) on the procedural body: shapes and finiteness, agreement of a new avatar
// with the skinned body model, gradients to every parameter, the inference cache, determinism, the parameter
// count formula and the checks of its inputs.
#include <cmath>
#include <limits>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include <ATen/CPUGeneratorImpl.h>
#include <ATen/Context.h>
#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <torch/serialize/input-archive.h>
#include <torch/serialize/output-archive.h>

#include "body/parts.h"
#include "body/skeleton.h"
#include "body/smplx.h"
#include "model/avatar.h"
#include "model/inference_cache.h"
#include "test_avatar_utils.h"
#include "test_body_utils.h"

namespace sfgs::testing {
namespace {

using model::Avatar;
using model::AvatarConfig;
using model::AvatarOutput;

// Every output tensor, by name, for comparisons between two outputs.
std::vector<std::pair<std::string, at::Tensor>> fields(const AvatarOutput& o) {
  return {{"means", o.means},
          {"covariances", o.covariances},
          {"opacities", o.opacities},
          {"colours", o.colours},
          {"canonical_means", o.canonical_means},
          {"log_scales", o.log_scales},
          {"mean_offset", o.mean_offset},
          {"structure_offset", o.structure_offset},
          {"scale_offset", o.scale_offset},
          {"colour_offset", o.colour_offset},
          {"hand_residual", o.hand_residual},
          {"posed_vertices", o.posed_vertices}};
}

void expect_identical(const AvatarOutput& a, const AvatarOutput& b) {
  const auto fa = fields(a), fb = fields(b);
  for (size_t i = 0; i < fa.size(); ++i) EXPECT_TRUE(fa[i].second.equal(fb[i].second)) << fa[i].first;
}

// The body model the avatar is built on, evaluated on its own (float32, axis-angle hands with the mean added).
body::Smplx reference_model(int64_t levels) {
  body::SmplxOptions o;
  o.num_betas = 10;
  o.num_expression_coeffs = 10;
  o.use_pca = false;
  o.subdivision_levels = levels;
  return body::Smplx(procedural_avatar_body().smplx, o);
}

body::SmplxInput reference_input(const body::SmplxPose& p) {
  body::SmplxInput in;
  in.betas = subject_betas().reshape({1, -1});
  for (const auto& field : body::SmplxPose::fields()) {
    const at::Tensor& value = p.*field.member;
    if (value.defined()) in.pose.*field.member = value.reshape({1, -1});
  }
  return in;
}

TEST(Avatar, OutputsHaveTheirShapesAndAreFinite) {
  Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 1);
  const AvatarOutput out = avatar->forward(test_pose(1, 0.4, /*hands=*/true), kTestTime);
  const int64_t n = avatar->gaussian_count();
  EXPECT_EQ(n, procedural_avatar_body().smplx.v_template.size(0));  // no subdivision
  for (const auto& [name, t] : fields(out)) {
    ASSERT_TRUE(t.defined()) << name;
    EXPECT_EQ(t.size(0), n) << name;
    EXPECT_EQ(t.scalar_type(), at::kFloat) << name;
    EXPECT_TRUE(at::isfinite(t).all().item<bool>()) << name;
    const bool per_point = name == "opacities" || name == "log_scales" || name == "scale_offset";
    EXPECT_EQ(t.dim(), per_point ? 1 : 2) << name;
    if (!per_point) EXPECT_EQ(t.size(1), name == "covariances" ? 6 : 3) << name;
  }
  EXPECT_TRUE(out.opacities.eq(1).all().item<bool>());
  EXPECT_GE(out.colours.min().item<double>(), 0.0);
  EXPECT_LE(out.colours.max().item<double>(), 1.0);
  // Posed covariances are symmetric positive definite.
  const at::Tensor& c = out.covariances;
  const at::Tensor full = at::stack({c.select(1, 0), c.select(1, 1), c.select(1, 2), c.select(1, 1), c.select(1, 3),
                                     c.select(1, 4), c.select(1, 2), c.select(1, 4), c.select(1, 5)},
                                    1)
                              .view({n, 3, 3});
  EXPECT_GT(at::linalg_eigvalsh(full.to(at::kDouble)).min().item<double>(), 0.0);
  // Labels cover every part; faces index the points.
  const at::Tensor labels = avatar->part_labels();
  EXPECT_EQ(labels.sizes(), at::IntArrayRef({n}));
  EXPECT_EQ(labels.scalar_type(), at::kByte);
  for (int64_t part = 0; part < body::kBodyPartCount; ++part) EXPECT_TRUE(labels.eq(part).any().item<bool>()) << part;
  EXPECT_EQ(avatar->faces().size(1), 3);
  EXPECT_LT(avatar->faces().max().item<int64_t>(), n);
}

// A new avatar (all output layers zero) is the skinned body-model mesh with the initial scales: the means match the
// body model evaluated on its own, and each covariance is sigma^2 A A^T with A the blended skinning Jacobian.
TEST(Avatar, NewAvatarReproducesTheSkinnedBodyModel) {
  AvatarConfig config = small_config();
  config.subdivision_levels = 1;
  Avatar avatar(procedural_avatar_body(), subject_betas(), config);
  const body::SmplxPose pose = test_pose(2, 0.5, /*hands=*/true);
  const AvatarOutput out = avatar->forward(pose, kTestTime);
  const body::Smplx smplx = reference_model(config.subdivision_levels);
  const body::SmplxOutput expected = smplx->forward(reference_input(pose));
  const at::Tensor vertices = expected.vertices[0];
  ASSERT_EQ(out.means.sizes(), vertices.sizes());
  EXPECT_LT(max_abs_difference(out.posed_vertices, vertices), 1e-5);
  EXPECT_LT(max_abs_difference(out.means, vertices), 1e-5);  // the procedural MANO hands equal SMPL-X's
  for (const at::Tensor& zero : {out.mean_offset, out.structure_offset, out.scale_offset, out.colour_offset})
    EXPECT_EQ(zero.abs().max().item<double>(), 0.0);
  EXPECT_LT(out.hand_residual.abs().max().item<double>(), 1e-6);
  EXPECT_TRUE(out.colours.eq(0.5).all().item<bool>());

  const at::Tensor weights = smplx->weights();
  const at::Tensor linear = expected.skinning_transforms[0].narrow(1, 0, 3).narrow(2, 0, 3).reshape({-1, 9});
  const at::Tensor a = weights.matmul(linear).view({-1, 3, 3});
  const at::Tensor gram = a.matmul(a.transpose(1, 2)) * (2 * out.log_scales).exp().view({-1, 1, 1});
  const at::Tensor packed =
      at::stack({gram.select(1, 0).select(1, 0), gram.select(1, 0).select(1, 1), gram.select(1, 0).select(1, 2),
                 gram.select(1, 1).select(1, 1), gram.select(1, 1).select(1, 2), gram.select(1, 2).select(1, 2)},
                1);
  EXPECT_LT(max_abs_difference(out.covariances, packed), 1e-6 * packed.abs().max().item<double>());

  // Initial scales: half the mean edge length at each point, between 0.1 mm (fingers) and 5 cm on this body.
  const at::Tensor sigma = out.log_scales.exp();
  EXPECT_GT(sigma.min().item<double>(), 1e-4);
  EXPECT_LT(sigma.max().item<double>(), 5e-2);
}

TEST(Avatar, RestPoseGivesTheCanonicalMeshTranslated) {
  AvatarConfig config = small_config();
  config.flat_hand_mean = true;
  Avatar avatar(procedural_avatar_body(), subject_betas(), config);
  body::SmplxPose pose;
  pose.transl = at::tensor({0.1, -0.2, 0.3}, at::kFloat);
  const AvatarOutput out = avatar->forward(pose, kTestTime);
  const at::Tensor shaped = reference_model(0)->forward(reference_input(body::SmplxPose{})).rest_vertices[0];
  EXPECT_LT(max_abs_difference(out.canonical_means, shaped), 1e-6);
  EXPECT_LT(max_abs_difference(out.means, shaped + pose.transl), 1e-6);
  const at::Tensor identity = at::tensor({1.0, 0.0, 0.0, 1.0, 0.0, 1.0}, at::kFloat);
  EXPECT_LT(max_abs_difference(out.covariances, (2 * out.log_scales).exp().unsqueeze(1) * identity), 1e-9);
}

TEST(Avatar, GradientsReachEveryParameter) {
  Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 3);
  const AvatarOutput out = avatar->forward(test_pose(3, 0.4, /*hands=*/true), kTestTime);
  at::Generator generator = at::detail::createCPUGenerator(3);
  const auto weigh = [&](const at::Tensor& t) { return (t * at::randn(t.sizes(), generator)).sum(); };
  (weigh(out.means) + weigh(out.covariances) + weigh(out.colours)).backward();
  int64_t checked = 0;
  for (const auto& p : avatar->named_parameters()) {
    ASSERT_TRUE(p.value().grad().defined()) << p.key();
    EXPECT_GT(p.value().grad().abs().sum().item<double>(), 0.0) << p.key();
    ++checked;
  }
  EXPECT_GT(checked, 30);
}

// The skeleton's gradient (fits' alignment passes) renders the same frame, and its pose gradient is the whole one less
// exactly the part that flows through the pose-driven networks' outputs (structure and colour offsets).
TEST(Avatar, ASkeletonGradientIsTheWholeOneWithoutThePoseDrivenNetworks) {
  Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 6);
  model::CanonicalAttributes attributes;
  {
    at::NoGradGuard no_grad;
    attributes = avatar->attributes(kTestTime);
  }
  body::SmplxPose pose = test_pose(6, 0.4, /*hands=*/true);
  pose.body_pose = pose.body_pose.clone().requires_grad_(true);
  at::Generator generator = at::detail::createCPUGenerator(6);
  const at::Tensor mean_weights = at::randn({avatar->gaussian_count(), 3}, generator);
  const at::Tensor colour_weights = at::randn({avatar->gaussian_count(), 3}, generator);
  const at::Tensor covariance_weights = at::randn({avatar->gaussian_count(), 6}, generator);
  const auto loss = [&](const AvatarOutput& o) {
    return (o.means * mean_weights).sum() + (o.colours * colour_weights).sum() +
           (o.covariances * covariance_weights).sum() * 1e3;
  };
  const AvatarOutput whole =
      avatar->forward_with_attributes(pose, attributes, /*has_time=*/true, model::PoseGradient::kWhole);
  const AvatarOutput skeleton =
      avatar->forward_with_attributes(pose, attributes, /*has_time=*/true, model::PoseGradient::kSkeleton);
  for (const auto& [name, a, b] : {std::tuple{"means", whole.means, skeleton.means},
                                   {"covariances", whole.covariances, skeleton.covariances},
                                   {"colours", whole.colours, skeleton.colours}})
    EXPECT_LT(max_abs_difference(a, b), 1e-6) << name;
  ASSERT_TRUE(whole.structure_offset.defined() && whole.colour_offset.defined());
  EXPECT_FALSE(skeleton.structure_offset.requires_grad());
  EXPECT_FALSE(skeleton.colour_offset.requires_grad());

  const at::Tensor whole_loss = loss(whole);
  const std::vector<at::Tensor> networks{whole.structure_offset, whole.scale_offset, whole.colour_offset};
  const auto through = torch::autograd::grad({whole_loss}, networks, {}, /*retain_graph=*/true);
  const at::Tensor network_path = torch::autograd::grad(networks, {pose.body_pose}, through, /*retain_graph=*/true)[0];
  const at::Tensor whole_gradient = torch::autograd::grad({whole_loss}, {pose.body_pose})[0];
  const at::Tensor skeleton_gradient = torch::autograd::grad({loss(skeleton)}, {pose.body_pose})[0];
  EXPECT_GT(network_path.abs().max().item<double>(), 1e-3 * whole_gradient.abs().max().item<double>());
  EXPECT_LT(max_abs_difference(skeleton_gradient + network_path, whole_gradient),
            1e-4 * whole_gradient.abs().max().item<double>());
}

TEST(Avatar, CachedInferenceEqualsUncached) {
  for (const bool hexplane : {true, false}) {
    AvatarConfig config = small_config();
    config.use_hexplane = hexplane;
    Avatar avatar(procedural_avatar_body(), subject_betas(), config);
    randomise_parameters(*avatar, 0.1, 4);
    avatar->eval();
    at::NoGradGuard no_grad;
    // a and b share a time, c is a's pose at another time.
    const body::SmplxPose a = test_pose(4, 0.4, true), b = test_pose(5, 0.4, true), c = a;
    const double ab_time = 0.3, c_time = -0.7;
    const AvatarOutput ua = avatar->forward(a, ab_time), ub = avatar->forward(b, ab_time),
                       uc = avatar->forward(c, c_time);
    avatar->cache_static_features();
    for (int repeat = 0; repeat < 2; ++repeat) {  // first fills the time-dependent part, then reuses it
      expect_identical(avatar->forward(a, ab_time), ua);
      expect_identical(avatar->forward(b, ab_time), ub);
      expect_identical(avatar->forward(c, c_time), uc);
    }
    avatar->train();
    expect_error([&] { avatar->forward(a, ab_time); }, {"cache", "clear_cache"});
    avatar->clear_cache();
    expect_identical(avatar->forward(a, ab_time), ua);
  }
}

// Moving or converting an avatar (avatar->to(...) rewrites every buffer in place) must never reach into the caller's
// body: the avatar keeps copies, not the caller's tensors.
TEST(Avatar, OwnsItsBuffersAndLeavesTheCallersBodyAlone) {
  const model::AvatarBody& body = procedural_avatar_body();
  const auto& x = body.smplx;
  const std::vector<std::pair<const char*, at::Tensor>> callers = {
      {"smplx.v_template", x.v_template},
      {"smplx.faces", x.faces},
      {"smplx.weights", x.weights},
      {"smplx.j_regressor", x.j_regressor},
      {"smplx.shapedirs", x.shapedirs},
      {"smplx.exprdirs", x.exprdirs},
      {"smplx.posedirs", x.posedirs},
      {"smplx.part_labels", x.part_labels},
      {"smplx.hands_mean_left", x.hands_mean_left},
      {"mano_left.v_template", body.mano_left.v_template},
      {"mano_right.faces", body.mano_right.faces},
      {"hand_vertex_ids.left", body.hand_vertex_ids.left},
      {"hand_vertex_ids.right", body.hand_vertex_ids.right},
      {"face_vertex_ids", body.face_vertex_ids}};
  std::vector<std::pair<std::string, at::ScalarType>> before;
  for (const auto& [name, t] : callers) before.emplace_back(name, t.defined() ? t.scalar_type() : at::kByte);
  Avatar avatar(body, subject_betas(), small_config());
  ASSERT_TRUE(body.has_mano);
  std::vector<at::Tensor> owned = avatar->buffers();
  for (const at::Tensor& p : avatar->parameters()) owned.push_back(p);
  for (const auto& [name, t] : callers) {
    if (!t.defined()) continue;
    for (const at::Tensor& o : owned)
      EXPECT_NE(o.storage().data(), t.storage().data()) << name << " is shared with the avatar";
  }
  avatar->to(at::kDouble);
  for (size_t i = 0; i < callers.size(); ++i)
    if (callers[i].second.defined()) EXPECT_EQ(callers[i].second.scalar_type(), before[i].second) << before[i].first;
}

TEST(Avatar, IsDeterministicForAFixedSeed) {
  const auto build = [](uint64_t seed) {
    at::manual_seed(seed);  // what torch::manual_seed calls
    return Avatar(procedural_avatar_body(), subject_betas(), small_config());
  };
  Avatar a = build(7), b = build(7), c = build(8);
  const auto pa = a->named_parameters(), pb = b->named_parameters(), pc = c->named_parameters();
  bool any_differs = false;
  for (const auto& p : pa) {
    EXPECT_TRUE(p.value().equal(pb[p.key()])) << p.key();
    any_differs = any_differs || !p.value().equal(pc[p.key()]);
  }
  EXPECT_TRUE(any_differs);
  const body::SmplxPose pose = test_pose(7, 0.4, true);
  expect_identical(a->forward(pose, kTestTime), b->forward(pose, kTestTime));
  expect_identical(a->forward(pose, kTestTime), a->forward(pose, kTestTime));
}

// What a checkpoint holds: saving one avatar and loading it into another built with a different seed makes the two
// give identical outputs (every buffer, the sparse skinning weights of the MANO layers included, survives).
TEST(Avatar, SaveAndLoadRoundTrips) {
  at::manual_seed(3);
  Avatar saved(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*saved, 0.1, 5);
  at::manual_seed(4);
  Avatar loaded(procedural_avatar_body(), subject_betas(), small_config());
  const body::SmplxPose pose = test_pose(9, 0.4, true);
  EXPECT_FALSE(saved->forward(pose, kTestTime).colours.equal(loaded->forward(pose, kTestTime).colours));
  torch::serialize::OutputArchive out;
  saved->save(out);
  std::ostringstream bytes;
  out.save_to(bytes);
  std::istringstream in_bytes(bytes.str());
  torch::serialize::InputArchive in;
  in.load_from(in_bytes);
  loaded->load(in);
  expect_identical(saved->forward(pose, kTestTime), loaded->forward(pose, kTestTime));
}

TEST(Avatar, ParameterCountFollowsTheFormulaForEverySwitchCombination) {
  for (int mask = 0; mask < 64; ++mask) {
    AvatarConfig config = small_config();
    config.use_hexplane = mask & 1;
    config.use_structure_offset = mask & 2;
    config.use_colour_offset = mask & 4;
    config.use_hand_residual = mask & 8;
    config.use_face_planes = mask & 16;
    config.use_shading = mask & 32;
    Avatar avatar(procedural_avatar_body(), subject_betas(), config);
    int64_t count = 0;
    for (const at::Tensor& p : avatar->parameters()) count += p.numel();
    EXPECT_EQ(count, model::parameter_count(config, /*has_mano=*/true)) << "switch mask " << mask;
  }
  model::AvatarBody without_mano = procedural_avatar_body();
  without_mano.has_mano = false;
  Avatar avatar(without_mano, subject_betas(), small_config());
  int64_t count = 0;
  for (const at::Tensor& p : avatar->parameters()) count += p.numel();
  EXPECT_EQ(count, model::parameter_count(small_config(), /*has_mano=*/false));
  EXPECT_LT(count, model::parameter_count(small_config(), /*has_mano=*/true));
  // The paper's configuration: planes dominate.
  EXPECT_GT(model::parameter_count(AvatarConfig{}, true), 10'000'000);
}

TEST(Avatar, ExpressionIsPaddedOrTruncated) {
  AvatarConfig config = small_config();
  config.num_expression_coeffs = 6;
  Avatar avatar(procedural_avatar_body(), subject_betas(), config);
  body::SmplxPose pose = test_pose(9, 0.3, false);
  pose.expression = at::tensor({0.5, -0.4, 0.3}, at::kFloat);
  const AvatarOutput short_expression = avatar->forward(pose, kTestTime);
  pose.expression = at::tensor({0.5, -0.4, 0.3, 0.0, 0.0, 0.0, 0.9, 0.9}, at::kFloat);  // 6 used
  const AvatarOutput long_expression = avatar->forward(pose, kTestTime);
  EXPECT_LT(max_abs_difference(long_expression.means, short_expression.means), 1e-6);
  EXPECT_LT(max_abs_difference(long_expression.colours, short_expression.colours), 1e-6);
  pose.expression = at::Tensor();
  EXPECT_GT(max_abs_difference(avatar->forward(pose, kTestTime).means, short_expression.means), 1e-4);
}

TEST(Avatar, RejectsBadInputsWithClearMessages) {
  Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  body::SmplxPose pose = test_pose(10, 0.3, true);
  expect_error([&] { avatar->forward(pose, 1.5); }, {"time", "[-1, 1]", "1.5"});
  pose = test_pose(10, 0.3, true);
  pose.body_pose = at::zeros({20, 3});
  expect_error([&] { avatar->forward(pose, kTestTime); }, {"body_pose", "(21, 3)", "[20, 3]"});
  pose = test_pose(10, 0.3, true);
  pose.transl = at::zeros({4});
  expect_error([&] { avatar->forward(pose, kTestTime); }, {"transl", "3"});
  // Non-finite values used to render an all-white image (every Gaussian culled) without a word.
  pose = test_pose(10, 0.3, true);
  pose.body_pose = at::full({21, 3}, std::nan(""));
  expect_error([&] { avatar->forward(pose, kTestTime); }, {"body_pose must be finite", "nan at index 0", "63 of 63"});
  pose = test_pose(10, 0.3, true);
  pose.body_pose = pose.body_pose.clone();
  pose.body_pose[4][1] = std::nan("");
  expect_error([&] { avatar->forward(pose, kTestTime); }, {"body_pose must be finite", "at index 13", "(1 of 63"});
  pose = test_pose(10, 0.3, true);
  pose.transl = at::tensor({0.0, std::numeric_limits<double>::infinity(), 0.0});
  expect_error([&] { avatar->forward(pose, kTestTime); }, {"transl must be finite", "inf at index 1"});
  expect_error([&] { Avatar(procedural_avatar_body(), at::zeros({2, 2, 2}), small_config()); }, {"betas", "[2, 2, 2]"});
  AvatarConfig config = small_config();
  config.hidden_width = 18;
  expect_error([&] { Avatar(procedural_avatar_body(), subject_betas(), config); }, {"hidden_width", "18"});
}

}  // namespace
}  // namespace sfgs::testing
