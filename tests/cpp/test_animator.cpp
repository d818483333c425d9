// The Animator (csrc/animate/animator.h) on the CPU, where its frames run eagerly: the same image as the avatar
// posed and rendered directly, and clear errors for what it refuses. Its CUDA graph frames are compared with eager
// ones in tests/cuda/test_animate_cuda.cpp.
#include <limits>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "animate/animator.h"
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
