// The training step's parts that make it recordable (train/training_step.h): the drawn step uploaded into buffers
// that keep their addresses, the kinds of step that may share a recorded graph, the camera applied on the device
// (a render at the origin of the Gaussians moved into the camera's frame is the camera's own render, gradients
// included), the avatar's device time (the host time's output exactly), and the frame cache that decodes ahead on
// a thread of its own (the dataset's frames, and a missing file's error at the step that draws it).
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include <chrono>
#include <filesystem>
#include <thread>

#include "common/constants.h"
#include "test_avatar_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/frame_cache.h"
#include "train/training_step.h"

namespace sfgs::testing {
namespace {

// The avatar seen from the front, a little from above and to the side (a camera away from the origin).
Camera side_camera(int64_t width, int64_t height) {
  Camera c = Camera::looking_forward(1.1 * double(height), width, height);
  const double angle = 0.4, cs = std::cos(angle), sn = std::sin(angle);
  // x rotated about y by `angle`, then y and z flipped (the body stands up along +y, the camera looks along -z).
  c.world_to_camera = {cs, 0, -sn, 0.05, 0, -1, 0, 0.3, -sn, 0, -cs, 3, 0, 0, 0, 1};
  return c;
}

train::StepData drawn_step(int64_t seed) {
  train::StepData d;
  at::manual_seed(seed);
  d.frame = at::randint(0, 256, {24, 20, 4}, at::kByte);
  d.pose = test_pose(seed, 0.3, true);
  d.camera = side_camera(20, 24);
  d.background = {0.1f * float(seed), 0.2f, 0.3f};
  d.time = 0.25;
  return d;
}

TEST(TrainStepInputs, HoldTheDrawnStepInBuffersThatKeepTheirAddresses) {
  const train::StepData first = drawn_step(1), second = drawn_step(2);
  train::StepInputs in(first, at::kCPU);
  in.upload(first);
  EXPECT_TRUE(in.frame.equal(first.frame));
  EXPECT_TRUE(at::allclose(in.background, at::tensor({0.1f, 0.2f, 0.3f})));
  ASSERT_TRUE(in.time.defined());
  EXPECT_FLOAT_EQ(in.time.item<float>(), 0.25f);
  EXPECT_TRUE(in.pose.body_pose.equal(first.pose.body_pose.to(at::kFloat)));
  EXPECT_TRUE(in.pose.right_hand_pose.equal(first.pose.right_hand_pose.to(at::kFloat)));
  EXPECT_TRUE(camera_at_origin(in.camera)) << "the kind renders at the origin; the camera pose is uploaded";
  EXPECT_EQ(in.camera.fx, first.camera.fx);

  const void* pose_address = in.pose.body_pose.data_ptr();
  const void* frame_address = in.frame.data_ptr();
  in.upload(second);
  EXPECT_EQ(in.pose.body_pose.data_ptr(), pose_address);
  EXPECT_EQ(in.frame.data_ptr(), frame_address);
  EXPECT_TRUE(in.pose.body_pose.equal(second.pose.body_pose.to(at::kFloat)));
  EXPECT_TRUE(in.frame.equal(second.frame));
  EXPECT_FLOAT_EQ(in.background[0].item<float>(), 0.2f);

  // A point in front of the camera lands where the camera's own transform puts it.
  const at::Tensor point = at::tensor({0.2f, 1.0f, -0.5f}).view({1, 3});
  const auto& m = second.camera.world_to_camera;
  const at::Tensor expected = at::tensor({float(m[0] * 0.2 + m[1] * 1.0 + m[2] * -0.5 + m[3]),
                                          float(m[4] * 0.2 + m[5] * 1.0 + m[6] * -0.5 + m[7]),
                                          float(m[8] * 0.2 + m[9] * 1.0 + m[10] * -0.5 + m[11])});
  EXPECT_TRUE(at::allclose(in.points_to_camera(point)[0], expected, 1e-6, 1e-6));
}

TEST(TrainStepInputs, KindsSeparateWhatARecordedStepBakesAndOnlyThat) {
  const train::StepData base = drawn_step(1);
  train::StepData other_values = drawn_step(2);  // other pose values, frame, background
  other_values.camera.world_to_camera[3] = 0.2;  // another camera pose
  EXPECT_EQ(train::step_kind(base), train::step_kind(other_values));
  train::StepData without_time = base;
  without_time.time.reset();
  train::StepData without_lpips = base;
  without_lpips.lpips = false;
  train::StepData other_focal = base;
  other_focal.camera.fx *= 1.1;
  train::StepData at_origin = base;
  at_origin.camera.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  train::StepData no_hands = base;
  no_hands.pose.left_hand_pose = no_hands.pose.right_hand_pose = at::Tensor();
  train::StepData larger = base;
  larger.frame = at::zeros({30, 20, 4}, at::kByte);
  for (const train::StepData* d : {&without_time, &without_lpips, &other_focal, &at_origin, &no_hands, &larger})
    EXPECT_NE(train::step_kind(base), train::step_kind(*d));
  EXPECT_THROW(train::StepInputs(train::StepData{at::zeros({4, 4, 3}, at::kByte)}, at::kCPU), c10::Error);
  // Buffers take only steps of their kind, and times on the hexplane's axis.
  train::StepInputs in(base, at::kCPU);
  expect_error_mentioning([&] { in.upload(without_time); }, "another kind");
  train::StepData late = base;
  late.time = 1.5;
  expect_error_mentioning([&] { in.upload(late); }, "[-1, 1]");
}

TEST(TrainStepInputs, RenderInTheCameraFrameEqualsTheCamerasRenderWithGradients) {
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 5);
  const train::StepData d = drawn_step(3);
  train::StepInputs in(d, at::kCPU);
  in.upload(d);
  const model::AvatarOutput out = avatar->forward(d.pose, d.time);
  const at::Tensor means = out.means.detach().requires_grad_(true);
  const at::Tensor covariances = out.covariances.detach().requires_grad_(true);
  const at::Tensor weights = at::rand({d.camera.height, d.camera.width, 3});

  const auto render_with = [&](bool camera_frame) {
    Gaussians g = model::to_gaussians(out);
    g.means = camera_frame ? in.points_to_camera(means) : means;
    g.covariances = camera_frame ? in.covariances_to_camera(covariances) : covariances;
    g.features = g.features.detach();
    const RenderResult r = render(g, in.background, camera_frame ? in.camera : d.camera);
    const auto grads = torch::autograd::grad({(r.image * weights).sum()}, {means, covariances});
    return std::vector<at::Tensor>{r.image.detach(), r.depth.detach(), grads[0], grads[1]};
  };
  const std::vector<at::Tensor> world = render_with(false), moved = render_with(true);
  ASSERT_GT(world[0].sub(in.background).abs().max().item<double>(), 0.1) << "the avatar must be in view";
  EXPECT_LT(max_abs_difference(world[0], moved[0]), 1e-4) << "image";
  EXPECT_LT(max_abs_difference(world[1], moved[1]), 1e-4) << "depth";
  for (size_t k : {2u, 3u}) {
    const double scale = world[k].abs().max().item<double>();
    ASSERT_GT(scale, 0);
    EXPECT_LT(max_abs_difference(world[k], moved[k]), 2e-3 * scale) << (k == 2 ? "means" : "covariances");
  }
}

TEST(Avatar, DeviceTimeGivesTheHostTimesOutput) {
  model::Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 6);
  const body::SmplxPose pose = test_pose(4, 0.3, true);
  const model::AvatarOutput host = avatar->forward(pose, kTestTime);
  const model::AvatarOutput device = avatar->forward_trusted_pose(pose, at::full({}, kTestTime, at::kFloat));
  EXPECT_TRUE(device.colours.equal(host.colours));
  EXPECT_TRUE(device.means.equal(host.means));
  const model::AvatarOutput host_none = avatar->forward(pose, std::nullopt);
  const model::AvatarOutput device_none = avatar->forward_trusted_pose(pose, at::Tensor());
  EXPECT_TRUE(device_none.colours.equal(host_none.colours));
  EXPECT_FALSE(device_none.colours.equal(device.colours)) << "the time branch must matter to this test";
  expect_error_mentioning([&] { avatar->forward_trusted_pose(pose, at::full({1}, kTestTime, at::kFloat)); }, "0-dim");
  expect_error_mentioning([&] { avatar->forward_trusted_pose(pose, at::full({}, kTestTime, at::kDouble)); }, "0-dim");
}

TEST(TrainFrameCache, DecodesAheadOnItsThreadAndGivesTheDatasetsFrames) {
  TempFolder folder;
  const data::Dataset video = tiny_video(folder, 5, 24);
  const std::vector<int64_t> train = video.split(data::Split::kTrain);
  ASSERT_GE(train.size(), 2u);
  train::FrameCache cache(video, train, /*page_locked=*/false);
  // The thread decodes every training frame without being asked.
  for (int wait = 0; wait < 600 && cache.kept() < int64_t(train.size()); ++wait)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(cache.kept(), int64_t(train.size()));
  for (int64_t f : train) {
    const data::Frame frame = video.load(f);
    const at::Tensor expected =
        at::cat({frame.image, frame.mask.unsqueeze(2)}, 2).mul(kEightBitMax).round().to(at::kByte);
    const at::Tensor got = cache.get(f);
    EXPECT_TRUE(got.equal(expected)) << "frame " << f;
    EXPECT_EQ(cache.get(f).data_ptr(), got.data_ptr()) << "a kept frame is decoded once";
  }
  // A frame nobody decoded yet whose file is gone: the step that draws it gets the reader's error.
  train::FrameCache lazy(video, {}, false);
  std::filesystem::remove(video.frames[size_t(train[1])].image_path);
  expect_error_mentioning([&] { lazy.get(train[1]); }, video.frames[size_t(train[1])].image_path);
}

}  // namespace
}  // namespace sfgs::testing
