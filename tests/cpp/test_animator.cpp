// The Animator (csrc/animate/animator.h) on the CPU, where its frames run eagerly: the same image as the avatar
// posed and rendered directly, and clear errors for what it refuses. Its CUDA graph frames are compared with eager
// ones in tests/cuda/test_animate_cuda.cpp.
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "animate/animator.h"
#include "animate/batch_animator.h"
#include "animate/visibility.h"
#include "ops/splat/camera_frame.h"
#include "metrics/image_metrics.h"
#include "test_avatar_utils.h"
#include "tensor_compare.h"
#include "animate/constants.h"

namespace sfgs::testing {
namespace {

// A camera 3 m in front of the body (+z), looking back at it with y up in the image.
Camera front_camera() {
  Camera c = Camera::looking_forward(60, 48, 64);
  c.world_to_camera = {1, 0, 0, 0, 0, -1, 0, 0.3, 0, 0, -1, 3, 0, 0, 0, 1};
  return c;
}

model::Avatar trained_looking_avatar() {
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 21);
  return avatar;
}

// The message of the error `call` raises ("no error" when it raises none).
std::string animator_error(const std::function<void()>& call) {
  try {
    call();
  } catch (const c10::Error& e) {
    return std::string(e.what_without_backtrace());
  }
  return std::string("no error");
}

TEST(Animator, CpuFrameEqualsTheAvatarPosedAndRenderedDirectly) {
  model::Avatar avatar = trained_looking_avatar();
  const at::Tensor background = at::full({3}, 0.25);
  animate::Animator animator(avatar, front_camera(), background);
  const body::SmplxPose pose = test_pose(3, 0.3, true);
  const at::Tensor image = animator.render(pose);

  at::NoGradGuard no_grad;
  const at::Tensor direct =
      render(model::to_gaussians(avatar->forward(pose, std::nullopt)), background, front_camera()).image;
  // The Animator splats in the camera's frame (a graph's camera is an input): equal up to float rounding.
  EXPECT_LT((image - direct).abs().max().item<double>(), 1e-5);
  EXPECT_GT((image - 0.25).abs().max().item<double>(), 0.1) << "the body is in view";
  EXPECT_EQ(animator.stats().frames, 1);
  EXPECT_EQ(animator.stats().graph_frames, 0);
}

TEST(Animator, ReplaysATrainingFrameWithItsTime) {
  model::Avatar avatar = trained_looking_avatar();
  const at::Tensor background = at::zeros({3});
  animate::Animator animator(avatar, front_camera(), background);
  const body::SmplxPose pose = test_pose(4, 0.3, false);
  const at::Tensor image = animator.render(pose, kTestTime);
  at::NoGradGuard no_grad;
  const at::Tensor direct =
      render(model::to_gaussians(avatar->forward(pose, kTestTime)), background, front_camera()).image;
  EXPECT_LT((image - direct).abs().max().item<double>(), 1e-5);
  EXPECT_GT((image - animator.render(pose)).abs().max().item<double>(), 1e-4) << "the time moves the frame";
}

TEST(Animator, FollowsAMovingCameraAndBackground) {
  model::Avatar avatar = trained_looking_avatar();
  animate::Animator animator(avatar, front_camera(), at::zeros({3}));
  const body::SmplxPose pose = test_pose(8, 0.3, true);
  at::NoGradGuard no_grad;
  const Gaussians posed = model::to_gaussians(avatar->forward(pose, std::nullopt));
  for (int k = 0; k < 3; ++k) {
    const double angle = 0.4 * k, c = std::cos(angle), s = std::sin(angle);
    Camera camera = front_camera();
    camera.world_to_camera = {c, 0, -s, 0, 0, -1, 0, 0.3, -s, 0, -c, 3, 0, 0, 0, 1};
    const at::Tensor background = at::full({3}, 0.1 * k);
    animator.set_camera(camera);
    animator.set_background(background);
    const at::Tensor image = animator.render(pose);
    const RenderResult direct = render(posed, background, camera);
    EXPECT_LT((image - direct.image).abs().max().item<double>(), 1e-5) << "camera " << k;
    EXPECT_LT((animator.latest().alpha - direct.alpha).abs().max().item<double>(), 1e-5) << "camera " << k;
    EXPECT_LT((animator.latest().depth - direct.depth).abs().max().item<double>(), 1e-4) << "camera " << k;
  }
}

// `n` random float64 Gaussians about the origin, with their full (N, 3, 3) covariances.
std::pair<Gaussians, at::Tensor> random_gaussians(int64_t n) {
  Gaussians g;
  g.means = at::randn({n, 3}, at::kDouble) * 0.3;
  const at::Tensor a = at::randn({n, 3, 3}, at::kDouble) * 0.05;
  const at::Tensor full = at::matmul(a, a.transpose(1, 2)) + 1e-4 * at::eye(3, at::kDouble);
  g.covariances =
      at::stack({full.select(1, 0).select(1, 0), full.select(1, 0).select(1, 1), full.select(1, 0).select(1, 2),
                 full.select(1, 1).select(1, 1), full.select(1, 1).select(1, 2), full.select(1, 2).select(1, 2)},
                1);
  g.opacities = at::rand({n}, at::kDouble) * 0.9;
  g.features = at::rand({n, 3}, at::kDouble);
  return {g, full};
}

// The placement of `camera` as a recording reads it from the device (float32 values, here in float64 tensors).
CameraFrame placement_of(const Camera& camera) {
  std::vector<float> values(kCameraFrameValues);
  write_camera_frame(camera, values.data());
  return CameraFrame(at::tensor(values, at::kFloat).to(at::kDouble));
}

// `g` moved into the frame of a camera's placement.
Gaussians moved_into(const Gaussians& g, const CameraFrame& frame) {
  Gaussians moved = g;
  moved.means = frame.points(g.means);
  moved.covariances = frame.covariances(g.covariances);
  return moved;
}

TEST(Animator, GaussiansMovedIntoTheCameraFrameRenderAsSeenByTheCamera) {
  // ops/splat/camera_frame.h: the Gaussians moved into the camera's frame give the same image, alpha and depth.
  at::manual_seed(3);
  const auto [g, full] = random_gaussians(300);
  Camera camera = Camera::looking_forward(80, 64, 48);
  const double c = std::cos(0.7), s = std::sin(0.7);
  camera.world_to_camera = {c, 0, s, 0.1, 0, 1, 0, -0.2, -s, 0, c, 2.5, 0, 0, 0, 1};
  const CameraFrame frame = placement_of(camera);
  const Gaussians moved_gaussians = moved_into(g, frame);
  const at::Tensor background = at::full({3}, 0.3, at::kDouble);
  const RenderResult seen = render(g, background, camera);
  const RenderResult moved = render(moved_gaussians, background, camera_at_origin_of(camera));
  EXPECT_GT(seen.alpha.max().item<double>(), 0.5) << "the Gaussians are in view";
  // The placement travels in float32: agreement to its rounding.
  EXPECT_LT((seen.image - moved.image).abs().max().item<double>(), 1e-5);
  EXPECT_LT((seen.alpha - moved.alpha).abs().max().item<double>(), 1e-5);
  EXPECT_LT((seen.depth - moved.depth).abs().max().item<double>(), 1e-5);
  // The covariance map is R Sigma R^T.
  const at::Tensor r = frame.rotation;
  const at::Tensor rotated = at::matmul(at::matmul(r, full), r.t());
  const at::Tensor packed = moved_gaussians.covariances;
  EXPECT_LT((packed.select(1, 1) - rotated.select(1, 0).select(1, 1)).abs().max().item<double>(), 1e-8);
  EXPECT_LT((packed.select(1, 5) - rotated.select(1, 2).select(1, 2)).abs().max().item<double>(), 1e-8);
  EXPECT_THROW(CameraFrame(at::zeros({12})), c10::Error);
}

TEST(Animator, CentredPrincipalPointGivesTheOffCentreCamerasImageAndGradients) {
  // A crop's camera, its principal point far off the image's centre (and Gaussians beyond the image's edges, where the
  // projection clamps): the sheared placement with the centred principal point gives the same image and gradients.
  at::manual_seed(4);
  const Gaussians g = random_gaussians(400).first;
  Camera camera = Camera::looking_forward(80, 40, 56);
  camera.cx = 6;
  camera.cy = 47;
  const double c = std::cos(0.4), s = std::sin(0.4);
  camera.world_to_camera = {c, 0, s, -0.2, 0, 1, 0, 0.1, -s, 0, c, 2.0, 0, 0, 0, 1};
  const Camera centred = with_centred_principal_point(camera);
  EXPECT_EQ(centred.cx, 20);
  EXPECT_EQ(centred.cy, 28);
  const at::Tensor background = at::full({3}, 0.3, at::kDouble);
  const at::Tensor weights = at::rand({56, 40, 3}, at::kDouble);
  const auto render_with = [&](bool sheared) {
    Gaussians leaf = g;
    leaf.means = g.means.clone().requires_grad_(true);
    leaf.covariances = g.covariances.clone().requires_grad_(true);
    const RenderResult r =
        sheared ? render(moved_into(leaf, placement_of(centred)), background, camera_at_origin_of(centred))
                : render(leaf, background, camera);
    const auto grads =
        torch::autograd::grad({(r.image * weights).sum() + r.alpha.sum()}, {leaf.means, leaf.covariances});
    return std::vector<at::Tensor>{r.image, r.alpha, r.depth, grads[0], grads[1]};
  };
  const std::vector<at::Tensor> seen = render_with(false), sheared = render_with(true);
  EXPECT_GT(seen[1].max().item<double>(), 0.5) << "the Gaussians are in view";
  EXPECT_GT(seen[1].select(1, 0).max().item<double>(), 0.2) << "and reach the crop's edge";
  const char* names[] = {"image", "alpha", "depth", "means' gradient", "covariances' gradient"};
  for (size_t k = 0; k < seen.size(); ++k) {
    // The placement travels in float32: agreement to its rounding.
    const double scale = std::max(1.0, seen[k].abs().max().item<double>());
    EXPECT_LT((seen[k] - sheared[k]).abs().max().item<double>(), 1e-4 * scale) << names[k];
  }
}

TEST(BackFacing, CullsExactlyThePointsFacingAwayByMoreThanTheMargin) {
  // Points on a unit sphere with outward normals, seen from a camera 4 m away on +z (rotated about the view axis,
  // so the centre comes from the full extrinsics).
  Camera camera = Camera::looking_forward(50, 32, 32);
  camera.world_to_camera = {0, -1, 0, 0, 1, 0, 0, 0, 0, 0, 1, 4, 0, 0, 0, 1};
  const std::array<double, 3> centre = camera_centre(camera);
  EXPECT_NEAR(centre[0], 0, 1e-12);
  EXPECT_NEAR(centre[1], 0, 1e-12);
  EXPECT_NEAR(centre[2], -4, 1e-12);
  const at::Tensor directions = at::randn({2000, 3}, at::kDouble);
  const at::Tensor normals = directions / directions.norm(2, 1, true);
  const at::Tensor means = normals.clone(), opacities = at::full({2000}, 0.7, at::kDouble);
  const at::Tensor centre_tensor = at::tensor({centre[0], centre[1], centre[2]}, at::kDouble);
  const double margin = 0.3;
  const at::Tensor kept = animate::cull_back_facing(opacities, means, normals, centre_tensor, margin);
  int64_t culled = 0;
  for (int64_t i = 0; i < 2000; ++i) {
    double dot = 0, length = 0;
    for (int c = 0; c < 3; ++c) {
      const double ray = means[i][c].item<double>() - centre[c];
      dot += normals[i][c].item<double>() * ray;
      length += ray * ray;
    }
    const bool away = dot > margin * std::sqrt(length);
    culled += away;
    EXPECT_EQ(kept[i].item<double>(), away ? 0.0 : 0.7) << "point " << i;
  }
  EXPECT_GT(culled, 600) << "the far side of the sphere";
  EXPECT_TRUE(animate::cull_back_facing(opacities, means, normals, centre_tensor, 1.0).equal(opacities));
}

TEST(Animator, CullingTheFarSideOfTheBodyLeavesTheImage) {
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.02, 22);
  const at::Tensor background = at::full({3}, 0.25);
  const Camera camera = front_camera();
  animate::AnimatorOptions fast;
  fast.back_facing_cosine = kAnimatorFastBackFacingCosine;
  animate::Animator culling(avatar, camera, background, fast);
  animate::Animator exact(avatar, camera, background);  // the default culls nothing
  const body::SmplxPose pose = test_pose(6, 0.3, true);
  const at::Tensor culled = culling.render(pose), whole = exact.render(pose);
  EXPECT_GT(metrics::psnr(culled, whole).item<double>(), 40.0);

  at::NoGradGuard no_grad;
  const model::AvatarOutput out = avatar->forward(pose, std::nullopt);
  const std::array<double, 3> centre = camera_centre(camera);
  const at::Tensor kept = animate::cull_back_facing(out.opacities, out.means, out.posed_normals,
                                                    at::tensor({centre[0], centre[1], centre[2]}, at::kFloat),
                                                    kAnimatorFastBackFacingCosine);
  EXPECT_LT(kept.mean().item<double>(), 0.7) << "a third or more of a body faces away from any camera";
}

TEST(Animator, RefusesNonFinitePosesAndBadBackgroundsOrCameras) {
  model::Avatar avatar = trained_looking_avatar();
  EXPECT_NE(animator_error([&] {
              animate::Animator(avatar, front_camera(), at::zeros({4}));
            }).find("background must be a floating (3) tensor"),
            std::string::npos);
  Camera bad = front_camera();
  bad.fx = -1;
  EXPECT_NE(animator_error([&] { animate::Animator(avatar, bad, at::zeros({3})); }).find("Animator: "),
            std::string::npos);
  animate::Animator animator(avatar, front_camera(), at::zeros({3}));
  body::SmplxPose pose = test_pose(5, 0.3, true);
  pose.body_pose = pose.body_pose.clone();
  pose.body_pose[2][1] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(animator_error([&] { animator.render(pose); }).find("body_pose must be finite"), std::string::npos);
  pose.body_pose = at::zeros({21, 3}, at::kInt);
  EXPECT_NE(animator_error([&] { animator.render(pose); }).find("pose.body_pose must be a floating tensor on the CPU"),
            std::string::npos);
}

// A batch on the CPU (one lane at a time, eager frames) gives each frame as an Animator renders it alone, stacked;
// cameras of different image sizes and a refused pose are clear errors, after which the next batch renders.
TEST(BatchAnimator, FramesEqualSingleFramesAndRefusalsLeaveItUsable) {
  model::Avatar avatar = trained_looking_avatar();
  const at::Tensor background = at::full({3}, 0.2);
  animate::BatchAnimator batch(avatar, background, {}, 2);
  animate::Animator single(avatar, front_camera(), background);
  std::vector<animate::BatchFrame> frames;
  for (int k = 0; k < 5; ++k) {
    const double angle = 0.3 * k, c = std::cos(angle), s = std::sin(angle);
    Camera camera = front_camera();
    camera.world_to_camera = {c, 0, -s, 0, 0, -1, 0, 0.3, -s, 0, -c, 3, 0, 0, 0, 1};
    frames.push_back(
        {camera, test_pose(30 + k, 0.3, k % 2 == 0), k == 3 ? model::FrameTime(kTestTime) : model::FrameTime()});
  }
  const RenderResult out = batch.render(frames);
  ASSERT_EQ(out.image.sizes(), at::IntArrayRef({5, 64, 48, 3}));
  ASSERT_EQ(out.alpha.sizes(), at::IntArrayRef({5, 64, 48}));
  ASSERT_EQ(out.radii.size(0), 5);
  for (size_t k = 0; k < frames.size(); ++k) {
    single.set_camera(frames[k].camera);
    const at::Tensor image = single.render(frames[k].pose, frames[k].time);
    EXPECT_EQ(max_difference(out.image[int64_t(k)], image), 0.0) << "frame " << k;
    EXPECT_EQ(max_difference(out.depth[int64_t(k)], single.latest().depth), 0.0) << "frame " << k;
    EXPECT_TRUE(out.visible[int64_t(k)].equal(single.latest().visible)) << "frame " << k;
  }
  EXPECT_GT(max_difference(out.image[0], out.image[1]), 1e-3) << "the frames differ";
  EXPECT_EQ(batch.stats().frames, 5);

  std::vector<animate::BatchFrame> sizes = {frames[0], frames[1]};
  sizes[1].camera = Camera::looking_forward(60, 32, 64);
  EXPECT_NE(animator_error([&] { batch.render(sizes); }).find("every camera needs one image size"), std::string::npos);
  std::vector<animate::BatchFrame> refused = frames;
  refused[3].pose.body_pose = refused[3].pose.body_pose.clone();
  refused[3].pose.body_pose[1][0] = std::numeric_limits<double>::infinity();
  EXPECT_NE(animator_error([&] { batch.render(refused); }).find("body_pose must be finite"), std::string::npos);
  EXPECT_EQ(max_difference(batch.render(frames).image, out.image), 0.0) << "usable after the refusal";
  EXPECT_NE(animator_error([&] { batch.render({}); }).find("at least one frame"), std::string::npos);
}

}  // namespace
}  // namespace sfgs::testing
