// The X-Humans reader on a fixture subject the test creates: takes, cameras.npz, depth-TIFF masks, converted SMPL-X
// parameters, splits, and the errors that point to the pickle converter.
#include <filesystem>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "data/dataset.h"
#include "io/npz.h"
#include "test_files.h"

namespace sfgs::data {
namespace {
namespace fs = std::filesystem;
using testing::expect_error_mentioning;
using testing::TempFolder;
using testing::write_text;

// One X-Humans subject: a train take with two frames and a test take with one.
void write_xhumans_take(const TempFolder& dir, const std::string& take, int frames, double focal) {
  const std::string base = "subject/" + take + "/";
  at::Tensor extrinsic = at::zeros({frames, 3, 4}, at::kDouble);
  for (int i = 0; i < frames; ++i) {
    const std::string number = std::to_string(i + 1);
    const std::string padded6 = std::string(6 - number.size(), '0') + number;
    const std::string padded5 = std::string(5 - number.size(), '0') + number;
    write_png(dir / (base + "render/image/color_" + padded6 + ".png"), at::full({6, 8, 3}, 0.25 * (i + 1)), true);
    cv::Mat depth(6, 8, CV_32F, cv::Scalar(10.0f));
    depth(cv::Rect(2, 1, 3, 2)) = 2.5f;  // the person: 3 x 2 pixels nearer than the far background
    ASSERT_TRUE(cv::imwrite(dir / (base + "render/depth/depth_" + padded6 + ".tiff"), depth));
    nlohmann::json pose{{"global_orient", {0.0, 0.0, 0.0}},
                        {"transl", {0.0, 0.0, 3.0 + i}},
                        {"body_pose", std::vector<double>(63, 0.01 * i)},
                        {"left_hand_pose", std::vector<double>(45, 0.0)},
                        {"right_hand_pose", std::vector<double>(45, 0.0)},
                        {"jaw_pose", {0.2, 0.0, 0.0}},
                        {"leye_pose", {0.0, 0.0, 0.0}},
                        {"reye_pose", {0.0, 0.0, 0.0}},
                        {"expression", std::vector<double>(10, 0.0)},
                        {"betas", std::vector<double>(10, 0.5)}};
    write_text(dir / (base + "SMPLX/mesh-f" + padded5 + "_smplx.json"), pose.dump());
    extrinsic[i][0][0] = extrinsic[i][1][1] = extrinsic[i][2][2] = 1.0;
    extrinsic[i][0][3] = 0.1 * i;
  }
  const at::Tensor intrinsic =
      at::tensor({focal, 0.0, 4.0, 0.0, focal + 1, 3.0, 0.0, 0.0, 1.0}, at::kDouble).view({3, 3});
  io::write_npz(dir / (base + "render/cameras.npz"), {{"intrinsic", intrinsic}, {"extrinsic", extrinsic}}, true);
}

TEST(XhumansDataset, ReadsTakesCamerasDepthMasksAndSplits) {
  TempFolder dir;
  write_xhumans_take(dir, "train/Take1", 2, 20.0);
  write_xhumans_take(dir, "test/Take4", 1, 30.0);
  const Dataset d = read_dataset(dir / "subject");
  EXPECT_EQ(d.format, "xhumans");
  ASSERT_EQ(d.size(), 3);
  EXPECT_EQ(d.sequences, (std::vector<std::string>{"train/Take1", "test/Take4"}));
  EXPECT_EQ(d.split(Split::kTrain), (std::vector<int64_t>{0, 1}));
  EXPECT_EQ(d.split(Split::kTest), (std::vector<int64_t>{2}));
  EXPECT_EQ(d.frames[1].camera.fx, 20.0);
  EXPECT_EQ(d.frames[1].camera.fy, 21.0);
  EXPECT_EQ(d.frames[1].camera.cx, 4.0);
  EXPECT_EQ(d.frames[1].camera.width, 8);
  EXPECT_EQ(d.frames[1].camera.world_to_camera[3], 0.1);
  EXPECT_EQ(d.frames[1].camera.world_to_camera[15], 1.0);
  EXPECT_EQ(d.frames[2].camera.fx, 30.0);
  EXPECT_EQ(d.frames[2].sequence, 1);
  EXPECT_FLOAT_EQ(d.frames[1].pose.transl[2].item<float>(), 4.0f);
  EXPECT_FLOAT_EQ(d.frames[1].pose.jaw_pose[0].item<float>(), 0.2f);
  EXPECT_FALSE(d.frames[1].pose_in_camera_frame);
  EXPECT_EQ(d.betas.numel(), 10) << "without smplx_optimized/ the fit's betas are used";
  const Frame f = d.load(0);
  EXPECT_EQ(f.mask.sum().item<float>(), 6.0f);
  EXPECT_EQ(f.mask[1][2].item<float>(), 1.0f);
  EXPECT_EQ(f.mask[0][0].item<float>(), 0.0f);
}

TEST(XhumansDataset, PicklesWithoutJsonAskForTheConverter) {
  TempFolder dir;
  write_xhumans_take(dir, "train/Take1", 1, 20.0);
  fs::remove(dir / "subject/train/Take1/SMPLX/mesh-f00001_smplx.json");
  write_text(dir / "subject/train/Take1/SMPLX/mesh-f00001_smplx.pkl", "pickle");
  expect_error_mentioning([&] { read_dataset(dir / "subject"); }, "convert_xhumans_smplx.py");
  write_xhumans_take(dir, "train/Take1", 1, 20.0);
  io::write_npz(dir / "subject/train/Take1/render/cameras.npz", {{"intrinsic", at::eye(3)}}, true);
  expect_error_mentioning([&] { read_dataset(dir / "subject"); }, "cameras.npz");
}

}  // namespace
}  // namespace sfgs::data
