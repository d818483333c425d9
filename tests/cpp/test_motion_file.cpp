// Motion files (csrc/data/motion_file.h): AMASS SMPL-X .npz in both layouts and SMPL-H, the Z-up to Y-up turn,
// resampling to another frame rate, and clear errors naming the key and the shape expected.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "body/rotations.h"
#include "data/motion_file.h"
#include "io/npz.h"
#include "test_files.h"

namespace sfgs::testing {
namespace {
namespace fs = std::filesystem;

std::string temp_path(const std::string& name) {
  const fs::path dir = fs::temp_directory_path() / "sfgs_motion_file_test";
  fs::create_directories(dir);
  return (dir / name).string();
}

using Arrays = std::vector<std::pair<std::string, at::Tensor>>;

std::string write(const std::string& name, const Arrays& arrays) {
  const std::string path = temp_path(name);
  io::write_npz(path, arrays, /*overwrite=*/true);
  return path;
}

TEST(MotionFile, ReadsAmassSmplxPosesAndTurnsZUpIntoYUp) {
  at::manual_seed(1);
  at::Tensor poses = 0.3 * at::randn({4, 165}, at::kDouble);
  poses[0].narrow(0, 0, 3).zero_();  // frame 0: no root rotation
  at::Tensor trans = at::randn({4, 3}, at::kDouble);
  trans[0] = at::tensor({0.0, 0.0, 1.0}, at::kDouble);  // one metre up in AMASS
  const std::string path = write("smplx.npz", {{"poses", poses},
                                               {"trans", trans},
                                               {"mocap_frame_rate", at::scalar_tensor(120.0, at::kDouble)},
                                               {"betas", at::zeros({16}, at::kDouble)}});
  const data::MotionClip clip = data::read_amass(path);
  ASSERT_EQ(clip.poses.size(), 4u);
  EXPECT_EQ(clip.frames_per_second, 120.0);
  EXPECT_EQ(clip.format, "amass-smplx");
  EXPECT_TRUE(clip.note.empty());
  EXPECT_TRUE(clip.poses[2].body_pose.equal(poses[2].narrow(0, 3, 63).view({21, 3})));
  EXPECT_TRUE(clip.poses[2].jaw_pose.equal(poses[2].narrow(0, 66, 3)));
  EXPECT_TRUE(clip.poses[2].reye_pose.equal(poses[2].narrow(0, 72, 3)));
  EXPECT_TRUE(clip.poses[2].left_hand_pose.equal(poses[2].narrow(0, 75, 45).view({15, 3})));
  EXPECT_TRUE(clip.poses[2].right_hand_pose.equal(poses[2].narrow(0, 120, 45).view({15, 3})));
  // Up (+Z) becomes +Y: the translation, and the root of a body standing upright in AMASS.
  EXPECT_TRUE(at::allclose(clip.poses[0].transl, at::tensor({0.0, 1.0, 0.0}, at::kDouble), 1e-12, 1e-12));
  const at::Tensor up = body::axis_angle_to_matrix(clip.poses[0].global_orient);
  EXPECT_TRUE(at::allclose(up.matmul(at::tensor({0.0, 0.0, 1.0}, at::kDouble)),
                           at::tensor({0.0, 1.0, 0.0}, at::kDouble), 1e-9, 1e-9));
  // Every frame's root is turned by the same rotation.
  const at::Tensor turn = up;
  const at::Tensor expected = turn.matmul(body::axis_angle_to_matrix(poses[3].narrow(0, 0, 3)));
  EXPECT_TRUE(at::allclose(body::axis_angle_to_matrix(clip.poses[3].global_orient), expected, 1e-9, 1e-9));
}

TEST(MotionFile, SeparateKeysReadAsThePosesLayout) {
  at::manual_seed(2);
  const at::Tensor poses = 0.3 * at::randn({3, 165}, at::kDouble), trans = at::randn({3, 3}, at::kDouble);
  const data::MotionClip whole = data::read_amass(
      write("whole.npz", {{"poses", poses}, {"trans", trans}, {"mocap_frame_rate", at::scalar_tensor(60.0)}}));
  const data::MotionClip split =
      data::read_amass(write("split.npz", {{"root_orient", poses.narrow(1, 0, 3).contiguous()},
                                           {"pose_body", poses.narrow(1, 3, 63).contiguous()},
                                           {"pose_jaw", poses.narrow(1, 66, 3).contiguous()},
                                           {"pose_eye", poses.narrow(1, 69, 6).contiguous()},
                                           {"pose_hand", poses.narrow(1, 75, 90).contiguous()},
                                           {"trans", trans},
                                           {"mocap_framerate", at::scalar_tensor(60.0)}}));
  ASSERT_EQ(split.poses.size(), whole.poses.size());
  for (size_t t = 0; t < whole.poses.size(); ++t)
    for (const body::SmplxPose::Field& f : body::SmplxPose::fields()) {
      const at::Tensor &a = whole.poses[t].*(f.member), &b = split.poses[t].*(f.member);
      ASSERT_EQ(a.defined(), b.defined()) << f.name;
      if (a.defined()) EXPECT_TRUE(at::allclose(a, b, 1e-12, 1e-12)) << f.name << " frame " << t;
    }
}

TEST(MotionFile, SmplhMotionsDriveBodyAndHandsWithANote) {
  const at::Tensor poses = 0.2 * at::randn({2, 156}, at::kDouble);
  const data::MotionClip clip =
      data::read_amass(write("smplh.npz", {{"poses", poses}, {"mocap_framerate", at::scalar_tensor(120.0)}}));
  EXPECT_EQ(clip.format, "amass-smplh");
  EXPECT_NE(clip.note.find("SMPL-H"), std::string::npos);
  EXPECT_TRUE(clip.poses[1].left_hand_pose.equal(poses[1].narrow(0, 66, 45).view({15, 3})));
  EXPECT_TRUE(clip.poses[1].right_hand_pose.equal(poses[1].narrow(0, 111, 45).view({15, 3})));
  EXPECT_EQ(clip.poses[1].jaw_pose.abs().sum().item<double>(), 0.0);
  EXPECT_EQ(clip.poses[1].transl.abs().sum().item<double>(), 0.0) << "no 'trans': at the origin";
}

TEST(MotionFile, BadFilesNameTheKeyAndTheShape) {
  const at::Tensor rate = at::scalar_tensor(30.0);
  expect_error_mentioning([&] { data::read_amass(temp_path("missing.npz")); }, "does not exist");
  expect_error_mentioning(
      [&] {
        data::read_amass(write("no_rate.npz", {{"poses", at::zeros({2, 165})}}));
      },
      "expected 'mocap_frame_rate' (AMASS SMPL-X) or 'mocap_framerate'");
  expect_error_mentioning(
      [&] {
        data::read_amass(write("wide.npz", {{"poses", at::zeros({2, 72})}, {"mocap_frame_rate", rate}}));
      },
      "'poses' must have shape (T, 165) (SMPL-X) or (T, 156) (SMPL-H)");
  expect_error_mentioning(
      [&] {
        data::read_amass(write("short.npz", {{"root_orient", at::zeros({3, 3})},
                                             {"pose_body", at::zeros({2, 63})},
                                             {"pose_hand", at::zeros({3, 90})},
                                             {"mocap_frame_rate", rate}}));
      },
      "'pose_body' must be a floating array of shape (3, 63)");
  expect_error_mentioning(
      [&] {
        data::read_amass(
            write("no_hands.npz",
                  {{"root_orient", at::zeros({3, 3})}, {"pose_body", at::zeros({3, 63})}, {"mocap_frame_rate", rate}}));
      },
      "lacks 'pose_hand' (expected shape (T, 90)");
  at::Tensor poses = at::zeros({2, 165});
  poses[1][7] = std::nan("");
  expect_error_mentioning(
      [&] {
        data::read_amass(write("nan.npz", {{"poses", poses}, {"mocap_frame_rate", rate}}));
      },
      "'poses' holds NaN or infinite values");
  expect_error_mentioning(
      [&] {
        data::read_amass(
            write("rate.npz", {{"poses", at::zeros({2, 165})}, {"mocap_frame_rate", at::scalar_tensor(0.0)}}));
      },
      "must be a positive frame rate");
}

TEST(MotionFile, ResamplesAlongTheShortestArc) {
  // Root turning about the vertical (AMASS Z) by 0.1 rad a frame, walking 0.1 m a frame.
  const int64_t frames = 9;
  at::Tensor poses = at::zeros({frames, 165}, at::kDouble), trans = at::zeros({frames, 3}, at::kDouble);
  for (int64_t t = 0; t < frames; ++t) {
    poses[t][2] = 0.1 * double(t);
    trans[t][0] = 0.1 * double(t);
  }
  const data::MotionClip clip = data::read_amass(
      write("turn.npz", {{"poses", poses}, {"trans", trans}, {"mocap_frame_rate", at::scalar_tensor(120.0)}}));
  const data::MotionClip slower = data::resample(clip, 30.0);  // every fourth frame, exactly
  ASSERT_EQ(slower.poses.size(), 3u);
  EXPECT_TRUE(slower.poses[2].global_orient.equal(clip.poses[8].global_orient));
  const data::MotionClip faster = data::resample(clip, 240.0);  // a frame between every two
  ASSERT_EQ(faster.poses.size(), 17u);
  const at::Tensor half = faster.poses[3].global_orient;  // between source frames 1 and 2: 0.15 rad about up
  const at::Tensor expected = data::read_amass(write("mid.npz", {{"poses",
                                                                  [&] {
                                                                    at::Tensor p = at::zeros({1, 165}, at::kDouble);
                                                                    p[0][2] = 0.15;
                                                                    return p;
                                                                  }()},
                                                                 {"mocap_frame_rate", at::scalar_tensor(1.0)}}))
                                  .poses[0]
                                  .global_orient;
  EXPECT_TRUE(at::allclose(half, expected, 1e-9, 1e-9)) << half << expected;
  EXPECT_NEAR(faster.poses[3].transl[0].item<double>(), 0.15, 1e-12);
  expect_error_mentioning([&] { data::resample(clip, 0); }, "must be positive");
}

}  // namespace
}  // namespace sfgs::testing
