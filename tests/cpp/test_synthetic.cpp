// `sfgs synth` on the built-in body: the dataset it writes reads back, its masks and meshes agree with its cameras,
// the motion moves body, fingers, jaw and expression, noisy fits keep the exact ones beside them, and the NeuMan
// layout places the same bodies in each camera.
#include <filesystem>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "body/procedural_body.h"
#include "body/smplx.h"
#include "data/dataset.h"
#include "data/image_io.h"
#include "data/motions.h"
#include "data/pose_noise.h"
#include "data/synthetic.h"
#include "io/npz.h"
#include "test_files.h"

namespace sfgs::data {
namespace {

TEST(SyntheticVideo, WritesAConsistentDatasetWithGroundTruthMeshes) {
  testing::TempFolder dir;
  SyntheticVideoOptions o;
  o.frames = 10;
  o.width = 48;
  o.height = 64;
  const Dataset written = write_synthetic_video(dir.str(), o);
  const Dataset d = read_dataset(dir.str());
  ASSERT_EQ(d.size(), 10);
  EXPECT_EQ(d.split(Split::kVal), std::vector<int64_t>{4});
  EXPECT_EQ(d.split(Split::kTest), std::vector<int64_t>{9});
  EXPECT_EQ(d.split(Split::kTrain).size(), 8u);
  const at::Tensor faces = io::read_npy(dir / "meshes/faces.npy");
  for (int64_t i : {0, 9}) {
    const Frame f = d.load(i);
    const double coverage = f.mask.mean().item<double>();
    EXPECT_GT(coverage, 0.05) << "the body must be in view";
    EXPECT_LT(coverage, 0.8);
    // Every ground-truth vertex projects into the image, and the projected centroid lands on the mask.
    const at::Tensor v = io::read_npy(d.frames[size_t(i)].mesh_path).to(at::kDouble);
    const auto& m = d.frames[size_t(i)].camera.world_to_camera;
    const at::Tensor r =
        at::tensor(std::vector<double>{m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]}).view({3, 3});
    const at::Tensor t = at::tensor(std::vector<double>{m[3], m[7], m[11]});
    const at::Tensor p = v.matmul(r.t()) + t;
    const Camera& c = d.frames[size_t(i)].camera;
    const at::Tensor u = c.fx * p.select(1, 0) / p.select(1, 2) + c.cx,
                     w = c.fy * p.select(1, 1) / p.select(1, 2) + c.cy;
    EXPECT_TRUE(((u >= 0) & (u < c.width) & (w >= 0) & (w < c.height)).all().item<bool>()) << "frame " << i;
    const int64_t px = int64_t(u.mean().item<double>()), py = int64_t(w.mean().item<double>());
    EXPECT_EQ(f.mask[py][px].item<float>(), 1.0f);
    EXPECT_LT(faces.max().item<int64_t>(), v.size(0));
  }
}

TEST(SyntheticVideo, MotionArticulatesBodyFingersJawAndExpression) {
  const SmplxPose a = motion_pose("sway", 0.0, 10), b = motion_pose("sway", 7 / 30.0, 10);
  EXPECT_GT((a.body_pose - b.body_pose).abs().max().item<float>(), 0.05f);
  EXPECT_GT((a.left_hand_pose - b.left_hand_pose).abs().max().item<float>(), 0.05f);
  EXPECT_GT((a.jaw_pose - b.jaw_pose).abs().max().item<float>(), 0.01f);
  EXPECT_GT((a.expression - b.expression).abs().max().item<float>(), 0.05f);
  EXPECT_TRUE(at::equal(motion_pose("sway", 7 / 30.0, 10).body_pose, b.body_pose)) << "deterministic";
}

TEST(SyntheticVideo, BadOptionsAreClearErrors) {
  testing::TempFolder dir;
  SyntheticVideoOptions o;
  o.frames = 0;
  testing::expect_error_mentioning([&] { write_synthetic_video(dir.str(), o); }, "--frames must be at least 1");
  o.frames = 2;
  o.body_model = dir / "missing.npz";
  testing::expect_error_mentioning([&] { write_synthetic_video(dir.str(), o); }, "missing.npz");
}

TEST(SyntheticVideo, NoisyFitsKeepTheExactOnesBesideThemAndTheImagesExact) {
  testing::TempFolder exact_dir, noisy_dir;
  SyntheticVideoOptions o;
  o.frames = 3;
  o.width = 48;
  o.height = 64;
  write_synthetic_video(exact_dir.str(), o);
  o.pose_noise = pose_noise_level("high");
  write_synthetic_video(noisy_dir.str(), o);
  const Dataset exact = read_dataset(exact_dir.str()), noisy = read_dataset(noisy_dir.str());
  EXPECT_FALSE(exact.frames[0].true_pose.has_value()) << "no truth is written beside exact fits";
  EXPECT_FALSE(exact.true_betas.defined());
  ASSERT_TRUE(noisy.true_betas.defined());
  EXPECT_TRUE(at::equal(noisy.true_betas, exact.betas));
  EXPECT_FALSE(at::equal(noisy.betas, exact.betas));
  for (int64_t i = 0; i < 3; ++i) {
    const FrameRecord &a = exact.frames[size_t(i)], &b = noisy.frames[size_t(i)];
    ASSERT_TRUE(b.true_pose.has_value());
    EXPECT_TRUE(at::equal(b.true_pose->body_pose, a.pose.body_pose));
    EXPECT_FALSE(at::equal(b.pose.body_pose, a.pose.body_pose));
    EXPECT_TRUE(at::equal(read_image_rgb(a.image_path), read_image_rgb(b.image_path))) << "images stay exact";
  }
}

// Noisy fits in the NeuMan layout: the reader takes ground_truth/ as the frames' true poses and the true shape.
TEST(SyntheticVideo, NeumanLayoutKeepsTheExactFitsBesideNoisyOnes) {
  testing::TempFolder exact_dir, noisy_dir;
  SyntheticVideoOptions o;
  o.frames = 3;
  o.width = 48;
  o.height = 64;
  o.layout = DatasetLayout::kNeuman;
  const Dataset exact = write_synthetic_video(exact_dir.str(), o);
  o.pose_noise = pose_noise_level("medium");
  const Dataset noisy = write_synthetic_video(noisy_dir.str(), o);
  ASSERT_TRUE(noisy.true_betas.defined());
  EXPECT_TRUE(noisy.true_betas.allclose(exact.betas));
  EXPECT_FALSE(noisy.betas.allclose(exact.betas)) << "the shape is corrupted too";
  for (size_t i = 0; i < noisy.frames.size(); ++i) {
    ASSERT_TRUE(noisy.frames[i].true_pose.has_value()) << i;
    EXPECT_TRUE(noisy.frames[i].true_pose->body_pose.allclose(exact.frames[i].pose.body_pose)) << i;
    EXPECT_TRUE(noisy.frames[i].true_pose->transl.allclose(exact.frames[i].pose.transl)) << i;
    EXPECT_FALSE(noisy.frames[i].pose.body_pose.allclose(exact.frames[i].pose.body_pose)) << i;
  }
}

TEST(SyntheticVideo, NeumanLayoutPlacesTheSameBodiesInEachCamera) {
  testing::TempFolder sfgs_dir, neuman_dir;
  SyntheticVideoOptions o;
  o.frames = 5;
  o.width = 48;
  o.height = 64;
  o.test_motions = {"wave"};
  write_synthetic_video(sfgs_dir.str(), o);
  o.layout = DatasetLayout::kNeuman;
  const Dataset d = write_synthetic_video(neuman_dir.str(), o);
  EXPECT_EQ(d.format, "neuman");
  EXPECT_EQ(d.size(), 10);
  // Every frame in one split: the held-out frame of the training motion in val_split.txt.
  EXPECT_EQ(d.split(Split::kTest), (std::vector<int64_t>{5, 6, 7, 8, 9}));
  EXPECT_EQ(d.split(Split::kTrain), (std::vector<int64_t>{0, 1, 2, 3}));
  EXPECT_EQ(d.split(Split::kVal), (std::vector<int64_t>{4}));
  for (const char* f : {"keypoints_whole_body/5.json", "ground_truth/shape_param.json",
                        "ground_truth/smplx_params/5.json", "masks/5.png", "images/00005.png"})
    EXPECT_TRUE(std::filesystem::exists(neuman_dir / f)) << f;
  // Camera-frame fits (hands relative to the mean) posed by SMPL-X equal the sfgs layout's meshes seen by the camera.
  const Dataset world = read_dataset(sfgs_dir.str());
  body::SmplxOptions options;
  options.use_pca = false;
  options.flat_hand_mean = false;
  options.dtype = at::kDouble;
  const body::Smplx layer(body::make_procedural_body().smplx, options);
  for (int64_t i : {0, 4}) {
    const FrameRecord& r = d.frames[size_t(i)];
    ASSERT_TRUE(r.pose_in_camera_frame);
    body::SmplxInput in;
    in.pose = body::SmplxPose::stack({r.pose}).to(at::TensorOptions().dtype(at::kDouble));
    in.betas = d.betas.to(at::kDouble).unsqueeze(0);
    const at::Tensor posed = layer->forward(in).vertices[0];
    const at::Tensor mesh = io::read_npy(world.frames[size_t(i)].mesh_path).to(at::kDouble);
    const auto& m = world.frames[size_t(i)].camera.world_to_camera;
    const at::Tensor rotation =
        at::tensor(std::vector<double>{m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]}).view({3, 3});
    const at::Tensor seen = mesh.matmul(rotation.t()) + at::tensor(std::vector<double>{m[3], m[7], m[11]});
    EXPECT_LT((posed - seen).abs().max().item<double>(), 1e-4) << "frame " << i;
  }
}

}  // namespace
}  // namespace sfgs::data
