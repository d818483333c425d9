// Pose fitting's evaluations recorded as CUDA graphs (train/pose_fit_evaluation.h) against the same loss run eagerly:
// loss and gradient to the correction at several corrections, frames with and without the time branch and a moving
// camera, both stages' losses, a frame that goes beyond the recorded splatting budget (recorded again), and a whole fit
// recorded against one run eagerly. Skips without a CUDA device.
#include <cmath>
#include <cstdio>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "common/device_graph.h"
#include "model/inference_cache.h"
#include "test_avatar_utils.h"
#include "train/pose_fit.h"
#include "train/pose_fit_evaluation.h"
#include "train/pose_refinement.h"

namespace sfgs::testing {
namespace {

constexpr int64_t kWidth = 96, kHeight = 128;

model::Avatar avatar_on_the_gpu(int64_t seed) {
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, seed);
  avatar->to(at::kCUDA);
  avatar->eval();
  avatar->cache_static_features();
  return avatar;
}

// A camera `distance` m in front of the body, turned by `angle` rad about the vertical. Its principal point lies inside
// a 16-pixel tile, so a body far enough away falls into that one tile.
Camera turned_camera(double angle, double distance) {
  Camera c = Camera::looking_forward(140.0, kWidth, kHeight);
  c.cx = 40;
  c.cy = 56;
  const double cs = std::cos(angle), sn = std::sin(angle);
  c.world_to_camera = {cs, 0, -sn, 0, 0, -1, 0, 0.3, -sn, 0, -cs, distance, 0, 0, 0, 1};
  return c;
}

// Frame k: a pose, a random target image and mask, the time branch in even frames.
train::FitFrame fit_frame(model::Avatar& avatar, int64_t k, double distance = 3.0) {
  at::manual_seed(200 + k);
  const at::TensorOptions gpu = at::TensorOptions(at::kCUDA);
  train::FitFrame f;
  const body::SmplxPose pose = test_pose(k, 0.3, true);
  f.pose = pose.views_of(pose.packed().to(at::kCUDA));
  const std::optional<double> time = k % 2 == 0 ? std::optional<double>(0.4 - 0.2 * double(k)) : std::nullopt;
  {
    at::NoGradGuard no_grad;
    f.attributes = avatar->attributes(time);
  }
  f.has_time = time.has_value();
  f.camera = turned_camera(0.1 * double(k), distance);
  f.camera.cx -= 3.0 * double(k);  // crops of one size at different places: one recording serves them all
  f.image = at::rand({kHeight, kWidth, 3}, gpu);
  f.mask = (at::rand({kHeight, kWidth}, gpu) > 0.5).to(at::kFloat);
  return f;
}

train::FitEvaluation eager(model::Avatar& avatar, const train::FitLoss& loss, const train::FitFrame& frame,
                           const at::Tensor& correction, bool run_loss) {
  const at::Tensor moving = correction.to(at::kCUDA, at::kFloat, false, true).requires_grad_(true);
  const at::Tensor value = loss(avatar, frame, moving, run_loss);
  return {value.item<double>(), torch::autograd::grad({value}, {moving})[0].cpu()};
}

void expect_same(const train::FitEvaluation& recorded, const train::FitEvaluation& reference, const std::string& what) {
  EXPECT_NEAR(recorded.loss, reference.loss, 1e-5 * (1 + std::abs(reference.loss))) << what;
  // The recorded evaluation projects through a float32 placement that holds the principal point's shear
  // (with_centred_principal_point); the eager one projects with the principal point itself. The SSIM and image-gradient
  // terms sum thousands of pixels' rounding: up to 1.5e-3 of the largest entry seen. (A wrong shear moves the image
  // by pixels: Animator.CentredPrincipalPointGivesTheOffCentreCamerasImageAndGradients.)
  const double scale = std::max(reference.gradient.abs().max().item<double>(), 1e-8);
  EXPECT_LT(max_abs_difference(recorded.gradient, reference.gradient), 3e-3 * scale) << what;
}

train::LossWeights without_lpips() {
  train::LossWeights w;
  w.use_lpips = false;
  return w;
}

TEST(PoseFitGraphsCuda, RecordedEvaluationsEqualEagerOnes) {
  if (!torch::cuda::is_available() || !device_graphs_available()) GTEST_SKIP() << "no CUDA device";
  model::Avatar avatar = avatar_on_the_gpu(11);
  const train::ImageLoss image_loss(without_lpips(), at::kCUDA);
  const train::FitLoss loss(image_loss, nullptr, 0.0);
  train::PoseFitGraphs graphs(avatar, loss, at::kCUDA);
  for (int64_t k = 0; k < 4; ++k) {
    const train::FitFrame frame = fit_frame(avatar, k);
    for (const bool run_loss : {false, true}) {
      graphs.load(frame, run_loss);
      at::manual_seed(300 + k);
      for (const at::Tensor& correction :
           {at::zeros({train::kCorrectionWidth}), 0.02 * at::randn({train::kCorrectionWidth})}) {
        const std::string what = "frame " + std::to_string(k) + (run_loss ? ", run loss" : ", L1 loss");
        expect_same(graphs.evaluate(correction), eager(avatar, loss, frame, correction, run_loss), what);
      }
    }
  }
  EXPECT_EQ(graphs.captures(), 4) << "one graph per loss with the time branch, one per loss without, whatever the "
                                     "principal point";
  // The body ten times farther away, inside one tile: that tile outgrows the recorded budget, which grows, and the
  // evaluation is recorded again and repeated on a whole image.
  const train::FitFrame far = fit_frame(avatar, 4, 30.0);
  graphs.load(far, true);
  const at::Tensor zero = at::zeros({train::kCorrectionWidth});
  expect_same(graphs.evaluate(zero), eager(avatar, loss, far, zero, true), "the far frame");
  EXPECT_EQ(graphs.captures(), 5) << "recorded again with a larger budget";
}

// The skeleton's gradient (alignment passes): the pose-driven networks run fused inside the recording as they do
// eagerly, and the gradient differs from the whole one (else the option would save nothing).
TEST(PoseFitGraphsCuda, RecordedSkeletonEvaluationsEqualEagerOnes) {
  if (!torch::cuda::is_available() || !device_graphs_available()) GTEST_SKIP() << "no CUDA device";
  model::Avatar avatar = avatar_on_the_gpu(13);
  const train::ImageLoss image_loss(without_lpips(), at::kCUDA);
  const train::FitLoss skeleton(image_loss, nullptr, 0.0, model::PoseGradient::kSkeleton);
  const train::FitLoss whole(image_loss, nullptr, 0.0, model::PoseGradient::kWhole);
  train::PoseFitGraphs graphs(avatar, skeleton, at::kCUDA);
  for (int64_t k = 0; k < 2; ++k) {
    const train::FitFrame frame = fit_frame(avatar, k);
    graphs.load(frame, true);
    at::manual_seed(400 + k);
    const at::Tensor correction = 0.02 * at::randn({train::kCorrectionWidth});
    const train::FitEvaluation reference = eager(avatar, skeleton, frame, correction, true);
    expect_same(graphs.evaluate(correction), reference, "frame " + std::to_string(k));
    const train::FitEvaluation full = eager(avatar, whole, frame, correction, true);
    EXPECT_NEAR(full.loss, reference.loss, 1e-4 * (1 + std::abs(full.loss))) << "the same frame, fused network";
    EXPECT_GT(max_abs_difference(full.gradient, reference.gradient), 1e-4 * full.gradient.abs().max().item<double>())
        << "the networks' share of the gradient";
  }
}

// A whole fit from a perturbed pose to the avatar's own render: the recorded fit moves towards the truth as the eager
// one does, and ends where it ends (L-BFGS follows the rounding of each gradient, so within a tolerance).
TEST(PoseFitGraphsCuda, ARecordedFitFindsThePoseAsTheEagerOneDoes) {
  if (!torch::cuda::is_available() || !device_graphs_available()) GTEST_SKIP() << "no CUDA device";
  model::Avatar avatar = avatar_on_the_gpu(12);
  const body::SmplxPose truth = test_pose(3, 0.2, true);
  train::PoseFitTarget target;
  target.camera = turned_camera(0.0, 3.0);
  target.time = 0.25;
  {
    at::NoGradGuard no_grad;
    const model::AvatarOutput out = avatar->forward(truth, target.time);
    const RenderResult r = render(model::to_gaussians(out), at::ones({3}, at::kCUDA), target.camera);
    target.mask = (r.alpha > 0.5).to(at::kFloat);
    target.image = r.image * target.mask.unsqueeze(2) + (1 - target.mask.unsqueeze(2));
  }
  body::SmplxPose start = truth;
  start.global_orient = truth.global_orient + at::tensor({0.f, 0.1f, 0.f});
  start.transl = truth.transl + at::tensor({0.04f, 0.f, 0.f});
  const train::PoseError before = train::pose_error(start, truth);
  std::vector<train::PoseError> ends;
  for (const bool recorded : {true, false}) {
    train::PoseFitOptions options;
    options.iterations = 100;
    options.loss = without_lpips();
    options.recorded = recorded;
    train::PoseFitter fitter(options, at::kCUDA, nullptr);
    const train::PoseFitResult fit = fitter.fit(avatar, start, target, at::zeros({train::kCorrectionWidth}));
    EXPECT_EQ(fit.recorded, recorded);
    EXPECT_GT(fit.evaluations, 10);
    EXPECT_LE(fit.loss, fit.start_loss);
    const train::PoseError after = train::pose_error(train::corrected_pose(start, fit.correction), truth);
    const std::string report =
        std::string(recorded ? "recorded: " : "eager: ") + train::to_string(before) + " -> " + train::to_string(after);
    EXPECT_LT(after.translation, 0.3 * before.translation) << report;
    EXPECT_LT(after.root, before.root) << report;
    ends.push_back(after);
  }
  EXPECT_NEAR(ends[0].root, ends[1].root, 0.5) << "recorded against eager, degrees";
  EXPECT_NEAR(ends[0].body, ends[1].body, 0.5) << "recorded against eager, degrees";
  EXPECT_NEAR(ends[0].translation, ends[1].translation, 0.3) << "recorded against eager, centimetres";

  // As an alignment pass fits: the skeleton's gradient, stages that end where the loss stalls.
  train::PoseFitOptions options;
  options.iterations = 100;
  options.loss = without_lpips();
  options.gradient = model::PoseGradient::kSkeleton;
  options.stall_share = train::kAlignmentStallShare;
  train::PoseFitter fitter(options, at::kCUDA, nullptr);
  const train::PoseFitResult fit = fitter.fit(avatar, start, target, at::zeros({train::kCorrectionWidth}));
  const train::PoseError after = train::pose_error(train::corrected_pose(start, fit.correction), truth);
  const std::string report = "skeleton: " + train::to_string(before) + " -> " + train::to_string(after) + " in " +
                             std::to_string(fit.evaluations) + " evaluations";
  EXPECT_LT(after.translation, 0.3 * before.translation) << report;
  EXPECT_LT(after.root, before.root) << report;
  std::printf("%s\n", report.c_str());
}

}  // namespace
}  // namespace sfgs::testing
