// The Animator (csrc/animate/animator.h) on the CPU, where its frames run eagerly: the same image as the avatar
// posed and rendered directly, and clear errors for what it refuses. Its CUDA graph frames are compared with eager
// ones in tests/cuda/test_animate_cuda.cpp.
#include <array>
#include <cmath>
#include <limits>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "animate/animator.h"
#include "animate/visibility.h"
#include "metrics/image_metrics.h"
#include "test_avatar_utils.h"

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

TEST(Animator, CpuFrameEqualsTheAvatarPosedAndRenderedDirectly) {
  model::Avatar avatar = trained_looking_avatar();
  const at::Tensor background = at::full({3}, 0.25);
  animate::Animator animator(avatar, front_camera(), background);
  const body::SmplxPose pose = test_pose(3, 0.3, true);
  const at::Tensor image = animator.render(pose);

  at::NoGradGuard no_grad;
  const at::Tensor direct = render(model::to_gaussians(avatar->forward(pose, std::nullopt)), background,
                                   front_camera()).image;
  EXPECT_TRUE(image.equal(direct));
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
  EXPECT_TRUE(image.equal(direct));
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
  const auto message = [](const std::function<void()>& call) {
    try {
      call();
    } catch (const c10::Error& e) {
      return std::string(e.what_without_backtrace());
    }
    return std::string("no error");
  };
  EXPECT_NE(message([&] { animate::Animator(avatar, front_camera(), at::zeros({4})); })
                .find("background must be a floating (3) tensor"),
            std::string::npos);
  Camera bad = front_camera();
  bad.fx = -1;
  EXPECT_NE(message([&] { animate::Animator(avatar, bad, at::zeros({3})); }).find("Animator: "), std::string::npos);
  animate::Animator animator(avatar, front_camera(), at::zeros({3}));
  body::SmplxPose pose = test_pose(5, 0.3, true);
  pose.body_pose = pose.body_pose.clone();
  pose.body_pose[2][1] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(message([&] { animator.render(pose); }).find("body_pose must be finite"), std::string::npos);
  pose.body_pose = at::zeros({21, 3}, at::kInt);
  EXPECT_NE(message([&] { animator.render(pose); }).find("pose.body_pose must be a floating tensor on the CPU"),
            std::string::npos);
}

}  // namespace
}  // namespace sfgs::testing
