// Motion files (csrc/data/motion_file.h): AMASS SMPL-X .npz in both layouts and SMPL-H, the Z-up to Y-up turn,
// resampling to another frame rate, clear errors naming the key and the shape expected, and the bounds checked before
// any work (frame rate, values, frame counts, ExAvatar frame sequences and cameras).
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <vector>
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
      "must be a frame rate in [1, 1000] frames/s, got 0");
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

namespace sfgs::testing {
namespace {

// An ExAvatar motion folder: frame files N.json of `poses` (camera coordinates) and, when given, cam_params/N.json.
std::string exavatar_folder(const std::string& name, const std::vector<body::SmplxPose>& poses,
                            const std::vector<std::pair<at::Tensor, at::Tensor>>& cameras) {
  const fs::path root = fs::path(temp_path(name));
  fs::remove_all(root);
  fs::create_directories(root / "smplx_optimized" / "smplx_params_smoothed");
  const auto list = [](const at::Tensor& t) {
    const at::Tensor flat = t.to(at::kDouble).contiguous().flatten();
    return std::vector<double>(flat.data_ptr<double>(), flat.data_ptr<double>() + flat.numel());
  };
  for (size_t k = 0; k < poses.size(); ++k) {
    const body::SmplxPose& p = poses[k];
    nlohmann::json j;
    j["root_pose"] = list(p.global_orient);
    j["body_pose"] = list(p.body_pose);
    j["jaw_pose"] = list(p.jaw_pose);
    j["leye_pose"] = list(p.leye_pose);
    j["reye_pose"] = list(p.reye_pose);
    j["lhand_pose"] = list(p.left_hand_pose);
    j["rhand_pose"] = list(p.right_hand_pose);
    j["expr"] = list(p.expression);
    j["trans"] = list(p.transl);
    std::ofstream(root / "smplx_optimized" / "smplx_params_smoothed" / (std::to_string(k + 7) + ".json")) << j.dump();
    if (k < cameras.size()) {
      fs::create_directories(root / "cam_params");
      nlohmann::json c;
      c["R"] = std::vector<std::vector<double>>{list(cameras[k].first[0]), list(cameras[k].first[1]),
                                                list(cameras[k].first[2])};
      c["t"] = list(cameras[k].second);
      c["focal"] = {1000.0, 1000.0};
      std::ofstream(root / "cam_params" / (std::to_string(k + 7) + ".json")) << c.dump();
    }
  }
  return root.string();
}

body::SmplxPose camera_pose(const at::Tensor& root, const at::Tensor& trans) {
  body::SmplxPose p = body::SmplxPose::zeros(10).to(at::TensorOptions().dtype(at::kDouble));
  p.global_orient = root;
  p.transl = trans;
  return p;
}

TEST(MotionFile, ExavatarFolderTurnsTheCameraFrameIntoTheAvatars) {
  // Values pass through ExAvatar's JSON as float32: compared to 1e-5.
  // A body upright in front of a static camera (image up is -y, the body faces the camera: -z), 3 m away.
  const at::Tensor facing = at::tensor({3.141592653589793, 0.0, 0.0}, at::kDouble);  // body +y up -> camera -y
  const std::string folder =
      exavatar_folder("exavatar_static", {camera_pose(facing, at::tensor({0.0, 0.0, 3.0}, at::kDouble))}, {});
  ASSERT_TRUE(data::is_motion_file(folder));
  const data::MotionClip clip = data::read_motion(folder);
  EXPECT_EQ(clip.format, "exavatar");
  EXPECT_FALSE(clip.absolute_hands);
  EXPECT_EQ(clip.frames_per_second, 30.0);
  // Upright and facing +z in the avatar's frame: the identity; in front of the camera: -z.
  EXPECT_TRUE(
      at::allclose(body::axis_angle_to_matrix(clip.poses[0].global_orient), at::eye(3, at::kDouble), 1e-5, 1e-5));
  EXPECT_TRUE(at::allclose(clip.poses[0].transl, at::tensor({0.0, 0.0, -3.0}, at::kDouble), 1e-5, 1e-5));
}

TEST(MotionFile, ExavatarFolderTakesAMovingCamerasMotionOut) {
  // A body standing still in the world, filmed by a camera that turns and moves: in every frame's camera coordinates
  // it differs, after reading it is the same.
  const at::Tensor world_root = at::tensor({3.0, 0.1, 0.2}, at::kDouble), world_trans = at::tensor({0.2, 0.1, 3.0});
  std::vector<body::SmplxPose> poses;
  std::vector<std::pair<at::Tensor, at::Tensor>> cameras;
  for (int k = 0; k < 3; ++k) {
    const at::Tensor r = body::axis_angle_to_matrix(at::tensor({0.05 * k, 0.3 * k, 0.0}, at::kDouble));
    const at::Tensor t = at::tensor({0.1 * k, -0.2 * k, 0.3 * k}, at::kDouble);
    poses.push_back(camera_pose(body::matrix_to_axis_angle(r.matmul(body::axis_angle_to_matrix(world_root))),
                                r.matmul(world_trans.to(at::kDouble)) + t));
    cameras.emplace_back(r, t);
  }
  const data::MotionClip clip = data::read_motion(exavatar_folder("exavatar_moving", poses, cameras));
  ASSERT_EQ(clip.poses.size(), 3u);
  for (size_t k = 1; k < 3; ++k) {
    EXPECT_TRUE(at::allclose(body::axis_angle_to_matrix(clip.poses[k].global_orient),
                             body::axis_angle_to_matrix(clip.poses[0].global_orient), 1e-5, 1e-5))
        << "frame " << k;
    EXPECT_TRUE(at::allclose(clip.poses[k].transl, clip.poses[0].transl, 1e-5, 1e-5)) << "frame " << k;
  }
  // A frame without its camera, while others have one, and a folder without frames are named.
  fs::remove(fs::path(temp_path("exavatar_moving")) / "cam_params" / "8.json");
  expect_error_mentioning([&] { data::read_motion(temp_path("exavatar_moving")); }, "frame 8 has no");
  const fs::path empty = fs::path(temp_path("exavatar_empty")) / "smplx_optimized" / "smplx_params_smoothed";
  fs::create_directories(empty);
  expect_error_mentioning([&] { data::read_motion(temp_path("exavatar_empty")); }, "holds no frame file like 0.json");
  expect_error_mentioning([&] { data::read_motion(temp_path("nowhere")); }, "is neither an AMASS .npz nor");
}

TEST(MotionFile, BoundsWhatAMotionMayHoldBeforeAnyWork) {
  const at::Tensor rate = at::scalar_tensor(100.0);
  // A frame rate that would resample 2 frames into 10^8.
  expect_error_mentioning(
      [&] {
        data::read_amass(
            write("slow.npz", {{"poses", at::zeros({2, 165})}, {"mocap_frame_rate", at::scalar_tensor(1e-6)}}));
      },
      "must be a frame rate in [1, 1000] frames/s, got 1e-06");
  // Poses and translations that are not a body's.
  at::Tensor huge = at::zeros({2, 165});
  huge[1][9] = 1e30;
  expect_error_mentioning(
      [&] {
        data::read_amass(write("huge.npz", {{"poses", huge}, {"mocap_frame_rate", rate}}));
      },
      "joint rotations beyond 100 rad are not a body's motion");
  expect_error_mentioning(
      [&] {
        data::read_amass(
            write("far.npz",
                  {{"poses", at::zeros({2, 165})}, {"trans", at::full({2, 3}, 1e30)}, {"mocap_frame_rate", rate}}));
      },
      "translations beyond 10000 m");
  // A long capture: only the seconds asked for are built (and the next frame, which they interpolate towards).
  at::Tensor poses = at::zeros({1000, 165});
  poses.select(1, 3).copy_(at::arange(1000) * 1e-3);
  const std::string long_file = write("long.npz", {{"poses", poses}, {"mocap_frame_rate", rate}});
  EXPECT_EQ(data::read_amass(long_file).poses.size(), 1000u);
  const data::MotionClip start = data::read_amass(long_file, 0.05);
  ASSERT_EQ(start.poses.size(), 7u);
  EXPECT_NEAR(start.poses[6].body_pose[0][0].item<double>(), 6e-3, 1e-8);  // written as float32
  EXPECT_EQ(data::resample(start, 100.0).poses.size(), 7u);
  // Resampling into more frames than a render takes is refused before it starts.
  expect_error_mentioning([&] { data::resample(start, 1e9); }, "frames; at most 200000");
}

TEST(MotionFile, ExavatarFoldersMustHoldConsecutiveFramesAndRotations) {
  const at::Tensor facing = at::tensor({3.141592653589793, 0.0, 0.0}, at::kDouble);
  const body::SmplxPose pose = camera_pose(facing, at::tensor({0.0, 0.0, 3.0}, at::kDouble));
  // Frames 7, 8 and 9 written, 8 removed.
  const std::string gap = exavatar_folder("exavatar_gap", {pose, pose, pose}, {});
  fs::remove(fs::path(gap) / "smplx_optimized" / "smplx_params_smoothed" / "8.json");
  expect_error_mentioning([&] { data::read_motion(gap); }, "jumps from frame 7 to 9 (8.json is missing)");
  for (const double scale : {0.0, 2.0}) {  // R = 0 and R = 2 I
    const std::string folder = exavatar_folder("exavatar_bad_camera", {pose},
                                               {{at::eye(3, at::kDouble) * scale, at::zeros({3}, at::kDouble)}});
    expect_error_mentioning([&] { data::read_motion(folder); },
                            "the rotation part of world_to_camera must be orthonormal with determinant +1");
  }
}

}  // namespace
}  // namespace sfgs::testing
