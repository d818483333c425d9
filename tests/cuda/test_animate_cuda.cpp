// The animation path on the GPU: the skinning kernel against the CPU reference (forward and gradients, float64 and
// float32); the fused gathered MLP (the structure offset's inference kernel), kinematic chain and vertex normals
// against their LibTorch references; the splatting op under a binning budget (within it: the plain render exactly;
// beyond it: only the background, with the true counts reported); the Animator's CUDA graph frames against eager
// frames, including a frame that outgrows its budget and a new pose layout; and the fast frame against the exact
// render. The *CudaSanitizer.* suites and AnimatorCuda.GraphFrame* run under compute-sanitizer in
// scripts/device_check.sh. Every test skips without a CUDA device.
#include <cmath>
#include <cstdio>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "animate/animator.h"
#include "animate/batch_animator.h"
#include "body/kinematics.h"
#include "body/mesh.h"
#include "body/rotations.h"
#include "ops/gathered_mlp/gathered_mlp.h"
#include "metrics/image_metrics.h"
#include "ops/skin/skin.h"
#include "test_avatar_utils.h"
#include "tensor_compare.h"
#include "body/constants.h"

namespace sfgs::testing {
namespace {

#define SKIP_WITHOUT_CUDA() \
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device"

void expect_skinning_parity(at::ScalarType dtype, int64_t n, double bound) {
  at::manual_seed(7);
  const auto cpu = at::TensorOptions().dtype(dtype);
  const int64_t j = 55;
  at::Tensor raw = at::rand({n, j}, cpu);
  raw = at::where(raw > 0.93, raw, at::zeros_like(raw)) + at::one_hot(at::randint(j, {n}), j).to(dtype);
  const at::Tensor dense = raw / raw.sum(1, true);
  at::Tensor transforms = at::eye(4, cpu).repeat({j, 1, 1});
  transforms.narrow(1, 0, 3).add_(0.3 * at::randn({j, 3, 4}, cpu));
  const at::Tensor means = at::randn({n, 3}, cpu), log_scales = -2 + 0.3 * at::randn({n}, cpu);
  const at::Tensor rest = at::randn({n, 3}, cpu);
  const at::Tensor grad_means = at::randn({n, 3}, cpu), grad_covariances = at::randn({n, 6}, cpu);
  const skin::SkinningWeights weights = skin::SkinningWeights::from_dense(dense);

  const at::Tensor grad_posed_rest = at::randn({n, 3}, cpu);
  // The transforms' gradient (a pose being fitted): a sum over every Gaussian, in another order on each device.
  const auto run = [&](at::Device device) {
    const at::Tensor m = means.to(device).requires_grad_(true), s = log_scales.to(device).requires_grad_(true);
    const at::Tensor t = transforms.to(device).requires_grad_(true);
    const skin::SkinnedGaussians out = skin::skin_gaussians(weights.to(device, dtype), t, m, s, rest.to(device));
    const at::Tensor loss = (out.means * grad_means.to(device)).sum() +
                            (out.covariances * grad_covariances.to(device)).sum() +
                            (out.posed_rest * grad_posed_rest.to(device)).sum();
    const auto g = torch::autograd::grad({loss}, {m, s, t});
    return std::vector<at::Tensor>{out.means, out.covariances, out.posed_rest, g[0], g[1], g[2]};
  };
  const std::vector<at::Tensor> on_cpu = run(at::kCPU), on_gpu = run(at::kCUDA);
  const char* names[] = {"means",         "covariances",        "posed rest",
                         "mean gradient", "log-scale gradient", "transform gradient"};
  for (size_t k = 0; k < on_cpu.size(); ++k)
    EXPECT_LT(max_difference(on_cpu[k], on_gpu[k]) / (1 + on_cpu[k].abs().max().item<double>()), bound)
        << names[k] << " " << dtype;
}

TEST(SkinCudaSanitizer, MatchesTheCpuReferenceInFloat64) {
  SKIP_WITHOUT_CUDA();
  expect_skinning_parity(at::kDouble, 5000, 1e-12);
}

TEST(SkinCuda, MatchesTheCpuReferenceInFloat32AtAvatarScale) {
  SKIP_WITHOUT_CUDA();
  expect_skinning_parity(at::kFloat, 200000, 1e-5);
}

// A camera 3 m in front of the body (+z), looking back at it with y up in the image.
Camera front_camera(int64_t width, int64_t height) {
  Camera c = Camera::looking_forward(1.2 * double(height), width, height);
  c.world_to_camera = {1, 0, 0, 0, 0, -1, 0, 0.3, 0, 0, -1, 3, 0, 0, 0, 1};
  return c;
}

model::Avatar cuda_avatar() {
  model::AvatarConfig config = small_config();
  config.subdivision_levels = 1;
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), config);
  randomise_parameters(*avatar, 0.1, 31);
  avatar->to(at::kCUDA);
  return avatar;
}

// An Animator's options for eager frames: the reference its graph frames are compared with.
animate::AnimatorOptions eager_animator_options() {
  animate::AnimatorOptions options;
  options.use_graph = false;
  return options;
}

TEST(BinningBudget, WithinItTheRenderIsThePlainOneAndBeyondItOnlyTheBackground) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  avatar->eval();
  at::NoGradGuard no_grad;
  const Gaussians g = model::to_gaussians(avatar->forward(test_pose(1, 0.3, true), std::nullopt));
  const at::Tensor background = at::tensor({0.2f, 0.4f, 0.6f}).cuda();
  const Camera camera = front_camera(96, 128);
  const at::Tensor plain = render(g, background, camera).image;
  const at::Tensor counts = at::zeros({BinningBudget::kCounts}, at::TensorOptions(at::kCUDA).dtype(at::kLong));
  const auto render_within = [&](const BinningBudget& budget) {
    RenderOptions options;
    options.budget = &budget;
    return render(g, background, camera, options).image;
  };
  const at::Tensor within = render_within(BinningBudget{1 << 22, 1 << 22, counts});
  EXPECT_TRUE(within.equal(plain));
  const at::Tensor reported = counts.cpu();
  const int64_t intersections = reported[0].item<int64_t>();
  EXPECT_GT(intersections, 0);
  EXPECT_GT(reported[1].item<int64_t>(), 0);
  EXPECT_EQ(reported[2].item<int64_t>(), 0);
  // A budget that fits exactly: the per-tile sort when the longest tile allows it (else the radix path again).
  EXPECT_TRUE(render_within(BinningBudget{intersections, reported[1].item<int64_t>(), counts}).equal(plain));

  const at::Tensor beyond = render_within(BinningBudget{intersections - 1, 1 << 22, counts});
  EXPECT_TRUE(beyond.equal(background.view({1, 1, 3}).expand_as(beyond)));
  EXPECT_EQ(counts.cpu()[0].item<int64_t>(), intersections);
}

// The fused kernel against the reference in float32 on the same (half-rounded) row inputs: what remains is the
// half-precision hidden layer input and weights, relative to the outputs' size.
double fused_mlp_error(int64_t n, int64_t outputs, int64_t groups, uint64_t seed) {
  at::manual_seed(seed);
  const auto gpu = at::TensorOptions(at::kCUDA);
  const int64_t h = gathered_mlp::kFusedWidth;
  const double bound = 1 / std::sqrt(double(h));
  gathered_mlp::GatheredMlpWeights w{bound * at::randn({h, h}, gpu), 0.1 * at::randn({h}, gpu),
                                     bound * at::randn({outputs, h}, gpu), 0.1 * at::randn({outputs}, gpu)};
  const at::Tensor rows = at::randn({n, h}, gpu).to(at::kHalf), group_rows = at::randn({groups, h}, gpu);
  const at::Tensor ids = at::randint(groups, {n}, gpu.dtype(at::kInt));
  at::NoGradGuard no_grad;
  EXPECT_TRUE(gathered_mlp::fuses(rows, w));
  const at::Tensor fused = gathered_mlp::gathered_mlp(rows, group_rows, ids, w);
  const at::Tensor reference = gathered_mlp::gathered_mlp_reference(rows, group_rows, ids, w);
  EXPECT_EQ(fused.sizes(), reference.sizes());
  if (n == 0) return 0;
  return max_difference(fused, reference) / reference.abs().max().item<double>();
}

TEST(GatheredMlpCudaSanitizer, FusedKernelMatchesTheReference) {
  SKIP_WITHOUT_CUDA();
  EXPECT_LT(fused_mlp_error(1007, 4, 55, 1), 5e-3) << "rows not a multiple of the warp's 16";
  EXPECT_LT(fused_mlp_error(5, 8, 3, 2), 5e-3) << "fewer rows than one warp's pass, the most outputs";
  EXPECT_LT(fused_mlp_error(64, 1, 1, 3), 5e-3) << "one output, one group";
  EXPECT_EQ(fused_mlp_error(0, 4, 55, 4), 0);
}

TEST(GatheredMlpCuda, FusedKernelMatchesTheReferenceAtAvatarScale) {
  SKIP_WITHOUT_CUDA();
  EXPECT_LT(fused_mlp_error(215782, 4, 55, 5), 5e-3);
}

TEST(GatheredMlpCuda, RowOfAGroupOutOfRangeIsNanAndTheOthersStay) {
  SKIP_WITHOUT_CUDA();
  const auto gpu = at::TensorOptions(at::kCUDA);
  const int64_t h = gathered_mlp::kFusedWidth;
  gathered_mlp::GatheredMlpWeights w{0.1 * at::randn({h, h}, gpu), at::randn({h}, gpu), at::randn({4, h}, gpu),
                                     at::randn({4}, gpu)};
  const at::Tensor rows = at::randn({40, h}, gpu).to(at::kHalf), group_rows = at::randn({5, h}, gpu);
  at::Tensor ids = at::randint(5, {40}, gpu.dtype(at::kInt));
  at::NoGradGuard no_grad;
  const at::Tensor before = gathered_mlp::gathered_mlp(rows, group_rows, ids, w);
  ids[17] = 5;
  ids[30] = -1;
  const at::Tensor after = gathered_mlp::gathered_mlp(rows, group_rows, ids, w).cpu();
  EXPECT_TRUE(after[17].isnan().all().item<bool>());
  EXPECT_TRUE(after[30].isnan().all().item<bool>());
  const at::Tensor others = at::ones({40}, at::kBool).index_fill_(0, at::tensor({17, 30}, at::kLong), false);
  EXPECT_TRUE(after.index({others}).equal(before.cpu().index({others})));

  // The reference, the path of a width the kernel does not take, gives such rows NaN as well, without reading the
  // groups on the host.
  gathered_mlp::GatheredMlpWeights narrow{at::randn({8, 8}, gpu), at::randn({8}, gpu), at::randn({2, 8}, gpu),
                                          at::randn({2}, gpu)};
  const at::Tensor narrow_rows = at::randn({40, 8}, gpu), narrow_groups = at::randn({5, 8}, gpu);
  ASSERT_FALSE(gathered_mlp::fuses(narrow_rows, narrow));
  const at::Tensor reference = gathered_mlp::gathered_mlp(narrow_rows, narrow_groups, ids, narrow).cpu();
  EXPECT_TRUE(reference[17].isnan().all().item<bool>());
  EXPECT_TRUE(reference[30].isnan().all().item<bool>());
  EXPECT_TRUE(reference.index({others}).isfinite().all().item<bool>());
}

// The fused kinematic chain against its LibTorch composition: the 55-joint SMPL-X tree (batch 3) and a 16-joint
// MANO-like tree (batch 1), random rotations, rest joints and translations.
TEST(KinematicChainCudaSanitizer, FusedChainMatchesTheReference) {
  SKIP_WITHOUT_CUDA();
  at::manual_seed(11);
  const std::vector<int64_t> mano{-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14};
  for (const std::vector<int64_t>& parents : {procedural_avatar_body().smplx.parents, mano}) {
    body::KinematicTree tree(parents);
    tree->to(at::kCUDA);
    const int64_t j = tree->size(), b = parents.size() == mano.size() ? 1 : 3;
    const auto gpu = at::TensorOptions(at::kCUDA);
    const at::Tensor rotations = body::axis_angle_to_matrix(0.6 * at::randn({b * j, 3}, gpu)).view({b, j, 3, 3});
    const at::Tensor rest = 0.3 * at::randn({b, j, 3}, gpu), translation = at::randn({b, 3}, gpu);
    ASSERT_TRUE(tree->fuses(rotations, rest, translation));
    const body::PosedSkeleton fused = tree->pose(rotations, rest, translation);
    const body::PosedSkeleton reference = tree->pose_reference(rotations, rest, translation);
    EXPECT_LT(max_difference(fused.joints, reference.joints), 1e-5) << j << " joints";
    EXPECT_LT(max_difference(fused.joint_transforms, reference.joint_transforms), 1e-5) << j << " joints";
    EXPECT_LT(max_difference(fused.skinning_transforms, reference.skinning_transforms), 1e-5) << j << " joints";
    EXPECT_FALSE(tree->fuses(rotations.clone().requires_grad_(true), rest, translation))
        << "a gradient through the pose takes the LibTorch composition";
    EXPECT_FALSE(tree->fuses(rotations.to(at::kDouble), rest.to(at::kDouble), translation.to(at::kDouble)));
  }
}

// The fused axis-angle rotations against their LibTorch composition: angles from zero through the series' range
// (below kRotationSeriesAngle) to several turns, in any batch shape; a gradient takes the composition.
TEST(AxisAngleCudaSanitizer, FusedRotationsMatchTheReference) {
  SKIP_WITHOUT_CUDA();
  at::manual_seed(13);
  const at::Tensor directions = at::randn({400, 3});
  const at::Tensor angles = at::cat({at::zeros({1}), at::logspace(-8, 1.3, 399)});  // up to 20 rad
  const at::Tensor axis_angle = (directions / directions.norm(2, 1, true) * angles.unsqueeze(1)).view({20, 20, 3});
  const at::Tensor gpu = axis_angle.cuda();
  const at::Tensor fused = body::axis_angle_to_matrix(gpu);
  EXPECT_EQ(fused.sizes(), at::IntArrayRef({20, 20, 3, 3}));
  EXPECT_LT(max_difference(fused, body::axis_angle_to_matrix_reference(gpu)), 5e-6);
  EXPECT_LT(max_difference(fused, body::axis_angle_to_matrix_reference(axis_angle.to(at::kDouble))), 2e-5);
  const at::Tensor orthogonality = at::matmul(fused, fused.transpose(-1, -2)) - at::eye(3, fused.options());
  EXPECT_LT(orthogonality.abs().max().item<double>(), 5e-6);
  const at::Tensor leaf = gpu.clone().requires_grad_(true);
  EXPECT_TRUE(body::axis_angle_to_matrix(leaf).requires_grad()) << "a gradient through the pose: the composition";
}

// The fused vertex normals against their LibTorch composition on the procedural body's mesh, moved off its rest
// shape, plus a vertex on no face (normal 0), a degenerate face and a face with a corner beyond the vertices
// (skipped); the same bits on every run, with the faces around the vertices given or made.
TEST(VertexNormalsCudaSanitizer, FusedNormalsMatchTheReference) {
  SKIP_WITHOUT_CUDA();
  at::manual_seed(12);
  const body::SmplxModelData& model = procedural_avatar_body().smplx;
  const int64_t v = model.v_template.size(0);
  const at::Tensor vertices =
      at::cat({model.v_template.to(at::kFloat) + 0.002 * at::randn({v, 3}), at::zeros({1, 3})}).cuda();
  const at::Tensor faces = at::cat({model.faces.to(at::kLong), at::tensor({0, 0, 1}, at::kLong).view({1, 3})}).cuda();
  const at::Tensor fused = body::vertex_normals(vertices, faces);
  const at::Tensor reference = body::vertex_normals_reference(vertices, faces);
  EXPECT_LT(max_difference(fused, reference), 1e-5);
  EXPECT_EQ(fused[v].abs().sum().item<double>(), 0.0) << "the vertex on no face";
  const at::Tensor lengths = fused.narrow(0, 0, v).norm(2, 1);
  EXPECT_LT((lengths - 1).abs().max().item<double>(), 1e-5);
  const body::VertexFaces around = body::vertex_faces(faces, v + 1);
  for (int run = 0; run < 3; ++run) EXPECT_TRUE(body::vertex_normals(vertices, faces, around).equal(fused)) << run;

  const at::Tensor stray = at::cat({faces, at::tensor({int64_t(1), int64_t(2), v + 7}, at::kLong).view({1, 3}).cuda()});
  EXPECT_TRUE(body::vertex_normals(vertices, stray).equal(fused)) << "a face beyond the vertices adds nothing";
  EXPECT_THROW(body::vertex_normals(vertices, stray, around), c10::Error) << "the faces around other faces";
}

TEST(AnimatorCuda, FastFrameMatchesTheExactRender) {
  SKIP_WITHOUT_CUDA();
  model::AvatarConfig config = small_config();
  config.subdivision_levels = 1;
  config.hidden_width = gathered_mlp::kFusedWidth;  // the width the fused structure offset runs at
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), config);
  randomise_parameters(*avatar, 0.02, 32);
  avatar->to(at::kCUDA);
  avatar->eval();
  const at::Tensor background = at::zeros({3}).cuda();  // the body's colours are near 0.5 at small parameters
  const Camera camera = front_camera(192, 256);
  const body::SmplxPose pose = test_pose(40, 0.3, true);
  at::Tensor exact;
  {
    at::NoGradGuard no_grad;
    avatar->clear_cache();  // the float32 LibTorch structure offset, every Gaussian splatted
    exact = render(model::to_gaussians(avatar->forward(pose, std::nullopt)), background, camera).image;
  }
  animate::Animator animator(avatar, camera, background);  // the fused structure offset, nothing culled
  const at::Tensor fast = animator.render(pose).clone();
  const double psnr = metrics::psnr(fast.cpu(), exact.cpu()).item<double>();
  EXPECT_GT(psnr, 50.0);
  EXPECT_GT(exact.cpu().max().item<double>(), 0.2) << "the body is in view";
  std::printf("fast frame vs exact render: PSNR %.1f dB\n", psnr);
}

TEST(AnimatorCuda, GraphFramesEqualEagerFramesOverAMotion) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  animate::Animator eager(avatar, front_camera(96, 128), background, eager_animator_options());
  animate::Animator graphed(avatar, front_camera(96, 128), background);
  for (int64_t k = 0; k < 6; ++k) {
    const body::SmplxPose pose = test_pose(10 + k, 0.1 + 0.1 * double(k), true);
    const at::Tensor from_graph = graphed.render(pose).clone();
    EXPECT_LT(max_difference(from_graph, eager.render(pose)), 1e-6) << "frame " << k;
  }
  EXPECT_EQ(graphed.stats().graph_frames, 6);
  EXPECT_GE(graphed.stats().captures, 1);
}

// With a sampling record coarser than the camera samples the body (model/sampling_filter.h): the graph frame widens the
// Gaussians as the eager one does, and the frame differs from the unwidened one.
TEST(AnimatorCuda, GraphFramesWidenGaussiansToTheirSamplingRecord) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  const body::SmplxPose pose = test_pose(17, 0.2, true);
  at::Tensor unwidened;
  {
    animate::Animator plain(avatar, front_camera(96, 128), background);
    unwidened = plain.render(pose).clone();
  }
  // Three times the footprint a 96 x 128 view 3 m away has: as if trained on images a third the size.
  const Camera camera = front_camera(96, 128);
  avatar->set_sampling_record(at::full({avatar->gaussian_count()}, 3 * 3.0 / std::sqrt(camera.fx * camera.fy)));
  animate::Animator eager(avatar, camera, background, eager_animator_options());
  animate::Animator graphed(avatar, camera, background);
  const at::Tensor from_graph = graphed.render(pose).clone();
  EXPECT_LT(max_difference(from_graph, eager.render(pose)), 1e-6);
  EXPECT_EQ(graphed.stats().graph_frames, 1);
  EXPECT_GT(max_difference(from_graph, unwidened), 0.05) << "widened";
}

TEST(AnimatorCuda, GraphFrameThatOutgrowsItsBudgetIsRenderedAgainWhole) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  // No headroom: the budget is exactly the first frame's count. That frame is one 16 x 16 tile, so every Gaussian
  // in view touches exactly one tile; the same view at 384 x 512 has the same Gaussians in view and those on a tile
  // border touch several: the budget is exceeded, grown, and the frame recorded and replayed again.
  animate::AnimatorOptions tight;
  tight.budget_slack = 1.0;
  const Camera one_tile = front_camera(16, 16), close = front_camera(384, 512);
  animate::Animator graphed(avatar, one_tile, background, tight);
  graphed.render(test_pose(20, 0.05, true));
  animate::Animator eager(avatar, close, background, eager_animator_options());
  graphed.set_camera(close);
  const body::SmplxPose pose = test_pose(21, 0.05, true);
  const at::Tensor from_graph = graphed.render(pose).clone();
  EXPECT_LT(max_difference(from_graph, eager.render(pose)), 1e-6);
  EXPECT_GE(graphed.stats().budget_overflows, 1)
      << "intersections " << graphed.stats().intersections << ", budget " << graphed.stats().budget;
}

TEST(AnimatorCuda, GraphFrameOfANewPoseLayoutCapturesAgain) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  animate::Animator graphed(avatar, front_camera(96, 128), background);
  animate::Animator eager(avatar, front_camera(96, 128), background, eager_animator_options());
  const body::SmplxPose with_hands = test_pose(30, 0.2, true), without_hands = test_pose(31, 0.2, false);
  graphed.render(with_hands);
  const int64_t captures = graphed.stats().captures;
  const at::Tensor from_graph = graphed.render(without_hands).clone();
  EXPECT_LT(max_difference(from_graph, eager.render(without_hands)), 1e-6);
  EXPECT_EQ(graphed.stats().captures, captures + 1);
}

// The camera circling the body: a new placement every frame, the same intrinsics.
Camera circling_camera(int64_t k) {
  const double angle = 0.25 * double(k), c = std::cos(angle), s = std::sin(angle);
  Camera camera = front_camera(96, 128);
  // Rotated about the body's vertical axis, then the front camera's flip and distance: [R | t] with R = F Ry.
  camera.world_to_camera = {c, 0, -s, 0, 0, -1, 0, 0.3, -s, 0, -c, 3, 0, 0, 0, 1};
  return camera;
}

TEST(AnimatorCuda, GraphFramesFollowAMovingCameraWithoutRecordingAgain) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  animate::Animator eager(avatar, circling_camera(0), background, eager_animator_options());
  animate::Animator graphed(avatar, circling_camera(0), background);
  at::NoGradGuard no_grad;
  for (int64_t k = 0; k < 5; ++k) {
    const body::SmplxPose pose = test_pose(50 + k, 0.2, true);
    graphed.set_camera(circling_camera(k));
    eager.set_camera(circling_camera(k));
    const at::Tensor from_graph = graphed.render(pose).clone();
    EXPECT_LT(max_difference(from_graph, eager.render(pose)), 1e-6) << "frame " << k;
    // The reference: the avatar posed and rendered by the camera itself (no move into its frame).
    const at::Tensor direct =
        render(model::to_gaussians(avatar->forward(pose, std::nullopt)), background.cuda(), circling_camera(k)).image;
    const double psnr = metrics::psnr(from_graph.cpu(), direct.cpu()).item<double>();
    std::printf("moving camera, frame %lld: graph vs direct render %.1f dB\n", static_cast<long long>(k), psnr);
    EXPECT_GT(psnr, 90.0) << "frame " << k;
  }
  EXPECT_EQ(graphed.stats().graph_frames, 5);
  EXPECT_EQ(graphed.stats().captures, 1) << "a new placement is an input of the recorded frame";
  Camera wider = circling_camera(0);
  wider.fx *= 0.8;
  graphed.set_camera(wider);
  graphed.render(test_pose(60, 0.2, true));
  EXPECT_EQ(graphed.stats().captures, 2) << "new intrinsics are recorded again";
}

TEST(AnimatorCuda, GraphFramesReplayTrainingTimesWithTheObservationPrior) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  // A third of the points well observed, the rest never: the prior's propagation runs in every timed frame.
  const int64_t n = avatar->gaussian_count();
  avatar->set_observation((at::arange(n) < n / 3).to(at::kFloat));
  const at::Tensor background = at::full({3}, 0.5);
  animate::Animator eager(avatar, front_camera(96, 128), background, eager_animator_options());
  animate::Animator graphed(avatar, front_camera(96, 128), background);
  const body::SmplxPose pose = test_pose(70, 0.2, false);
  at::Tensor previous;
  for (const double time : {-0.9, -0.1, 0.4, 0.95}) {
    const at::Tensor from_graph = graphed.render(pose, time).clone();
    EXPECT_LT(max_difference(from_graph, eager.render(pose, time)), 1e-6) << "time " << time;
    if (previous.defined()) EXPECT_GT(max_difference(from_graph, previous), 1e-4) << "the time moves the frame";
    previous = from_graph;
  }
  EXPECT_EQ(graphed.stats().graph_frames, 4);
  EXPECT_EQ(graphed.stats().captures, 1) << "the time is an input of the recorded frame";
  const at::Tensor new_motion = graphed.render(pose).clone();
  EXPECT_LT(max_difference(new_motion, eager.render(pose)), 1e-6);
  EXPECT_EQ(graphed.stats().captures, 2) << "a frame without a time is recorded apart";
}

// A batch on several streams (three lanes for seven frames, new and replayed, the camera turning): every frame equals
// the eager frame of its pose, the results stay the caller's after the next batch, and each lane recorded its graph;
// a batch of one frame (on the caller's stream) too.
TEST(AnimatorCuda, BatchFramesOnSeveralStreamsEqualEagerFrames) {
  SKIP_WITHOUT_CUDA();
  model::Avatar avatar = cuda_avatar();
  const at::Tensor background = at::full({3}, 0.5);
  animate::Animator eager(avatar, front_camera(96, 128), background, eager_animator_options());
  animate::BatchAnimator batch(avatar, background, {}, 3);
  std::vector<animate::BatchFrame> frames;
  for (int64_t k = 0; k < 7; ++k) {
    const double angle = 0.2 * double(k), c = std::cos(angle), s = std::sin(angle);
    Camera camera = front_camera(96, 128);
    camera.world_to_camera = {c, 0, -s, 0, 0, -1, 0, 0.3, -s, 0, -c, 3, 0, 0, 0, 1};
    frames.push_back(
        {camera, test_pose(40 + k, 0.1 + 0.05 * double(k), true), k >= 5 ? model::FrameTime(0.3) : model::FrameTime()});
  }
  const RenderResult out = batch.render(frames);
  std::vector<animate::BatchFrame> next = frames;
  for (auto& f : next) f.pose = test_pose(60, 0.3, true);
  batch.render(next);
  for (size_t k = 0; k < frames.size(); ++k) {
    eager.set_camera(frames[k].camera);
    const at::Tensor image = eager.render(frames[k].pose, frames[k].time);
    EXPECT_LT(max_difference(out.image[int64_t(k)], image), 1e-6) << "frame " << k;
    EXPECT_LT(max_difference(out.alpha[int64_t(k)], eager.latest().alpha), 1e-6) << "frame " << k;
  }
  // A batch of one frame, on the caller's stream.
  const RenderResult one = batch.render({frames[2]});
  eager.set_camera(frames[2].camera);
  EXPECT_LT(max_difference(one.image[0], eager.render(frames[2].pose, frames[2].time)), 1e-6);
  EXPECT_EQ(batch.lane_count(), 3);
  EXPECT_EQ(batch.stats().graph_frames, 15);
  EXPECT_GE(batch.stats().captures, 3);
}

}  // namespace
}  // namespace sfgs::testing
