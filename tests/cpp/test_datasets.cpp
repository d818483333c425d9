// Dataset readers and the writer on fixture folders the tests create: sfgs's own format round trip, the
// ExAvatar-preprocessed NeuMan layout, and clear errors for missing or corrupt files.
#include <filesystem>
#include <fstream>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "data/neuman.h"
#include "test_files.h"

namespace sfgs::data {
namespace {
namespace fs = std::filesystem;
using testing::expect_error_mentioning;
using testing::TempFolder;
using testing::write_text;

Dataset small_dataset(const TempFolder& dir) {
  Dataset d;
  d.source = dir.str();
  d.format = "sfgs";
  d.sequences = {"walk"};
  d.betas = at::arange(10, at::kFloat) / 10;
  for (int i = 0; i < 3; ++i) {
    FrameRecord r;
    r.name = "frame" + std::to_string(i);
    r.time = 0.5 * i;
    r.camera = Camera::looking_forward(20.0 + i, 8, 6);
    r.camera.world_to_camera[3] = 0.1 * i;
    r.pose = SmplxPose::zeros(10);
    r.pose.body_pose[3][1] = 0.25f * float(i);
    r.pose.transl[2] = 3.0f;
    r.image_path = dir / ("images/" + r.name + ".png");
    r.mask_path = dir / ("masks/" + r.name + ".png");
    write_png(r.image_path, at::rand({6, 8, 3}), false);
    write_png(r.mask_path, (at::rand({6, 8}) > 0.5).to(at::kFloat), false);
    d.frames.push_back(r);
  }
  d.splits[Split::kTrain] = {0, 1};
  d.splits[Split::kTest] = {2};
  return d;
}

TEST(SfgsDataset, WriteThenReadGivesTheSameDataset) {
  TempFolder dir;
  const Dataset d = small_dataset(dir);
  write_sfgs_dataset(d, dir.str(), false);
  const Dataset back = read_dataset(dir.str());
  EXPECT_EQ(back.format, "sfgs");
  ASSERT_EQ(back.size(), 3);
  EXPECT_EQ(back.sequences, d.sequences);
  EXPECT_TRUE(at::allclose(back.betas, d.betas));
  EXPECT_EQ(back.split(Split::kTrain), (std::vector<int64_t>{0, 1}));
  EXPECT_EQ(back.split(Split::kTest), (std::vector<int64_t>{2}));
  EXPECT_TRUE(back.split(Split::kVal).empty());
  for (int64_t i = 0; i < 3; ++i) {
    const FrameRecord &a = d.frames[size_t(i)], &b = back.frames[size_t(i)];
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.time, b.time);
    EXPECT_EQ(a.camera.world_to_camera, b.camera.world_to_camera);
    EXPECT_EQ(a.camera.fx, b.camera.fx);
    EXPECT_TRUE(at::equal(a.pose.body_pose, b.pose.body_pose));
    EXPECT_TRUE(at::equal(a.pose.transl, b.pose.transl));
    EXPECT_EQ(fs::canonical(a.image_path), fs::canonical(b.image_path));
    const Frame f = back.load(i);
    EXPECT_EQ(f.image.sizes(), at::IntArrayRef({6, 8, 3}));
    EXPECT_TRUE(at::equal(f.mask, read_mask(a.mask_path, MaskEncoding::kWhitePerson)));
  }
  // Times normalised over the training frames (0 and 1); the test frame after them replays nothing: no time.
  EXPECT_DOUBLE_EQ(*back.replay_time(0), -1.0);
  EXPECT_DOUBLE_EQ(*back.replay_time(1), 1.0);
  EXPECT_FALSE(back.replay_time(2).has_value());
  expect_error_mentioning([&] { write_sfgs_dataset(d, dir.str(), false); }, "refusing to overwrite");
}

TEST(Dataset, ReplayTimeReachesPastTheTrainingSpanAsFarAsAHeldOutFrameInsideIt) {
  // Ten frames 0.1 s apart, frames 4 and 9 held out (the interleaved split's pattern), then 1.2 s: far past the end.
  Dataset d;
  d.sequences = {"sway"};
  for (int i = 0; i < 11; ++i) {
    FrameRecord r;
    r.time = i < 10 ? 0.1 * i : 1.2;
    d.frames.push_back(r);
  }
  d.splits[Split::kTrain] = {0, 1, 2, 3, 5, 6, 7, 8};
  d.splits[Split::kTest] = {4, 9, 10};
  EXPECT_NEAR(*d.replay_time(4), 2 * 0.4 / 0.8 - 1, 1e-12) << "between training frames";
  ASSERT_TRUE(d.replay_time(9).has_value()) << "one frame past the last training frame: as near as frame 4";
  EXPECT_DOUBLE_EQ(*d.replay_time(9), 1.0) << "clamped to the end of the trained axis";
  EXPECT_FALSE(d.replay_time(10).has_value()) << "beyond what training saw";
  // The trainer's clock, built once, answers the same.
  const ReplayClock clock(d);
  for (int64_t i = 0; i < d.size(); ++i) EXPECT_EQ(clock.time_of(d.frames[size_t(i)]), d.replay_time(i)) << i;
}

TEST(SfgsDataset, PngRoundTripIsExactAt8Bits) {
  TempFolder dir;
  const at::Tensor image = at::randint(0, 256, {5, 7, 3}).to(at::kFloat) / 255;
  write_png(dir / "a.png", image, false);
  EXPECT_TRUE(at::allclose(read_image_rgb(dir / "a.png"), image, 0, 1e-7));
}

TEST(SfgsDataset, CorruptAndInconsistentFilesAreClearErrors) {
  TempFolder dir;
  expect_error_mentioning([&] { read_dataset(dir.str() + "/missing"); }, "does not exist");
  expect_error_mentioning([&] { read_dataset(dir.str()); }, "is not a dataset folder");
  write_text(dir / "dataset.json", "{ not json");
  expect_error_mentioning([&] { read_dataset(dir.str()); }, "dataset.json' is not valid JSON");
  write_text(dir / "dataset.json", R"({"format": "other", "version": 1})");
  expect_error_mentioning([&] { read_dataset(dir.str()); }, "expected format 'sfgs-dataset'");
  const Dataset d = small_dataset(dir);
  write_sfgs_dataset(d, dir.str(), true);
  write_text(d.frames[1].image_path, "garbage");
  expect_error_mentioning([&] { read_dataset(dir.str()).load(1); }, "frame1.png");
  expect_error_mentioning([&] { read_dataset(dir.str()).load(1); }, "not a PNG or JPEG image");
  // A PNG cut short (a copy or download that stopped): said in words, not stb's "outofdata".
  write_png(d.frames[1].image_path, at::rand({32, 32, 3}), true);
  std::filesystem::resize_file(d.frames[1].image_path, std::filesystem::file_size(d.frames[1].image_path) / 2);
  expect_error_mentioning([&] { read_dataset(dir.str()).load(1); }, "cut short or damaged");
  Dataset twins = d;
  twins.frames[1].name = twins.frames[0].name;
  expect_error_mentioning([&] { write_sfgs_dataset(twins, dir.str(), true); },
                          "frames 0 and 1 share the name '" + d.frames[0].name + "'");
  Dataset bad = d;
  bad.splits[Split::kVal] = {7};
  expect_error_mentioning([&] { write_sfgs_dataset(bad, dir.str(), true); }, "split 'val' names frame 7");
  bad = d;
  bad.frames[0].pose.body_pose = at::zeros({20, 3});
  expect_error_mentioning([&] { write_sfgs_dataset(bad, dir.str(), true); }, "body_pose has shape");
}

// A camera whose rotation is singular, and a non-finite pose value, in dataset.json: named by frame and field.
TEST(SfgsDataset, BadCamerasAndPoseValuesInTheIndexAreNamed) {
  TempFolder dir;
  const Dataset d = small_dataset(dir);
  write_sfgs_dataset(d, dir.str(), true);
  const std::string index = dir.str() + "/dataset.json";
  nlohmann::json j = nlohmann::json::parse(std::ifstream(index));
  j["frames"][1]["camera"]["world_to_camera"] = {0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  write_text(index, j.dump());
  expect_error_mentioning([&] { read_dataset(dir.str()); },
                          "frame '" + d.frames[1].name +
                              "' camera: the rotation part of world_to_camera must be "
                              "orthonormal with determinant +1");
  j = nlohmann::json::parse(std::ifstream(index));
  j["frames"][1]["camera"]["world_to_camera"] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  j["frames"][0]["smplx"]["transl"] = {0, 12345.5, 0};
  std::string text = j.dump();
  text.replace(text.find("12345.5"), 7, "1e400");  // JSON has no NaN or Inf: an overflowing number is the way in
  write_text(index, text);
  expect_error_mentioning([&] { read_dataset(dir.str()); }, "number overflow parsing '1e400'");
}

// Paths of dataset.json stay inside the dataset folder: '..' and absolute paths are refused by frame and field.
TEST(SfgsDataset, IndexPathsStayInsideTheDatasetFolder) {
  TempFolder dir;
  const Dataset d = small_dataset(dir);
  write_sfgs_dataset(d, dir.str(), true);
  const std::string index = dir.str() + "/dataset.json";
  const nlohmann::json written = nlohmann::json::parse(std::ifstream(index));
  for (const auto& [field, path] : std::vector<std::pair<std::string, std::string>>{{"image", "../other/frame0.png"},
                                                                                    {"image", "/etc/passwd"},
                                                                                    {"mask", "masks/../../m.png"},
                                                                                    {"keypoints", "/tmp/k.json"}}) {
    nlohmann::json j = written;
    j["frames"][1][field] = path;
    write_text(index, j.dump());
    expect_error_mentioning([&] { read_dataset(dir.str()); },
                            "frames[1]." + field + " '" + path + "' leaves the dataset folder");
  }
  // A name with dots that is not '..' stays allowed.
  nlohmann::json j = written;
  j["frames"][1]["mask"] = "masks/..hidden.png";
  write_text(index, j.dump());
  EXPECT_EQ(read_dataset(dir.str()).frames[1].mask_path, dir.str() + "/masks/..hidden.png");
}

// A two-frame NeuMan folder as ExAvatar's preprocessing leaves it.
void write_neuman_fixture(const TempFolder& dir) {
  write_text(dir / "sparse/cameras.txt", "# Camera list\n1 PINHOLE 8 6 20.5 21.5 4.25 2.75\n");
  // Frame 1 is rotated 90 degrees about z: quaternion (cos 45, 0, 0, sin 45).
  write_text(dir / "sparse/images.txt",
             "# Image list\n1 1 0 0 0 0.1 0.2 0.3 1 00000.png\n\n2 0.7071067811865476 0 0 0.7071067811865476 0 0 1 1 "
             "00001.png\n1.0 2.0 -1\n");
  for (const char* name : {"00000", "00001"}) {
    write_png(dir / (std::string("images/") + name + ".png"), at::full({6, 8, 3}, 0.5), true);
    at::Tensor seg = at::ones({6, 8});
    seg.slice(0, 2, 4).slice(1, 3, 6).zero_();  // the person is black in NeuMan segmentations
    write_png(dir / (std::string("segmentations/") + name + ".png"), seg, true);
  }
  write_png(dir / "masks/0.png", at::zeros({6, 8}).index_fill_(0, at::tensor({1}, at::kLong), 1.0), true);
  write_text(dir / "smplx_optimized/shape_param.json", "[0.1, 0.2, 0.3]");
  write_text(dir / "smplx_optimized/joint_offset.json", "[[0, 0, 0], [0.01, 0, 0]]");
  const auto triples = [](int n, double first) {  // nested [[x, y, z], ...] as ExAvatar writes them
    std::string s = "[";
    for (int k = 0; k < n; ++k) s += (k ? ", [" : "[") + std::to_string(k == 0 ? first : 0.0) + ", 0, 0]";
    return s + "]";
  };
  for (int frame = 0; frame < 2; ++frame)
    write_text(dir / ("smplx_optimized/smplx_params/" + std::to_string(frame) + ".json"),
               "{\"root_pose\": [0.1, 0, 0], \"body_pose\": " + triples(21, 0.3 * frame) +
                   ", \"jaw_pose\": [0, 0, 0], \"leye_pose\": [0, 0, 0], \"reye_pose\": [0, 0, 0], \"lhand_pose\": " +
                   triples(15, 0.2) + ", \"rhand_pose\": " + triples(15, -0.2) +
                   ", \"expr\": [0.5, 0.25], \"trans\": [0, 0.5, 3]}");
  write_text(dir / "train_split.txt", "00000.png\n");
  write_text(dir / "test_split.txt", "00001.png\n");
}

TEST(NeumanDataset, ReadsCamerasPosesMasksAndSplits) {
  TempFolder dir;
  write_neuman_fixture(dir);
  const Dataset d = read_dataset(dir.str());
  EXPECT_EQ(d.format, "neuman");
  ASSERT_EQ(d.size(), 2);
  EXPECT_EQ(d.split(Split::kTrain), std::vector<int64_t>{0});
  EXPECT_EQ(d.split(Split::kTest), std::vector<int64_t>{1});
  EXPECT_EQ(d.betas.numel(), 3);
  const FrameRecord& a = d.frames[0];
  EXPECT_EQ(a.camera.fx, 20.5);
  EXPECT_EQ(a.camera.cy, 2.75);
  EXPECT_EQ(a.camera.world_to_camera[3], 0.1);
  EXPECT_EQ(a.camera.world_to_camera[11], 0.3);
  // 90 degrees about z maps x to y: row-major R = [[0, -1, 0], [1, 0, 0], [0, 0, 1]].
  const FrameRecord& b = d.frames[1];
  EXPECT_NEAR(b.camera.world_to_camera[1], -1.0, 1e-12);
  EXPECT_NEAR(b.camera.world_to_camera[4], 1.0, 1e-12);
  EXPECT_NEAR(b.camera.world_to_camera[0], 0.0, 1e-12);
  EXPECT_TRUE(b.pose_in_camera_frame);
  EXPECT_FLOAT_EQ(b.pose.body_pose[0][0].item<float>(), 0.3f);
  EXPECT_FLOAT_EQ(b.pose.left_hand_pose[0][0].item<float>(), 0.2f);
  EXPECT_EQ(b.pose.expression.numel(), 2);
  EXPECT_GT(b.time, a.time);
  // Frame 0 has a SAM mask (row 1); frame 1 falls back to the segmentation. Both evaluate on the segmentation.
  const Frame f0 = d.load(0), f1 = d.load(1);
  EXPECT_EQ(f0.mask.sum().item<float>(), 8.0f);
  EXPECT_EQ(f1.mask.sum().item<float>(), 6.0f);
  EXPECT_EQ(f0.eval_mask.sum().item<float>(), 6.0f);
  EXPECT_EQ(f0.eval_mask[2][3].item<float>(), 1.0f);
}

TEST(NeumanDataset, MissingOrBadFilesAreClearErrors) {
  TempFolder dir;
  write_neuman_fixture(dir);
  fs::remove(dir / "smplx_optimized/smplx_params/1.json");
  expect_error_mentioning([&] { read_dataset(dir.str()); }, "smplx_params/1.json");
  write_neuman_fixture(dir);
  write_text(dir / "sparse/cameras.txt", "1 OPENCV 8 6 20 20 4 3 0.1 0.1 0 0\n");
  expect_error_mentioning([&] { read_dataset(dir.str()); }, "camera model OPENCV has lens distortion");
  write_neuman_fixture(dir);
  write_text(dir / "smplx_optimized/smplx_params/0.json", "{\"root_pose\": [0, 0]}");
  expect_error_mentioning([&] { read_dataset(dir.str()); }, "root_pose: expected 3 numbers, got 2");
}

}  // namespace
}  // namespace sfgs::data
