// `sfgs synth` on the built-in body: the dataset it writes reads back, its masks and meshes agree with its cameras,
// and the motion moves body, fingers, jaw and expression.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "data/dataset.h"
#include "data/motions.h"
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
    const at::Tensor r = at::tensor(std::vector<double>{m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]}).view({3, 3});
    const at::Tensor t = at::tensor(std::vector<double>{m[3], m[7], m[11]});
    const at::Tensor p = v.matmul(r.t()) + t;
    const Camera& c = d.frames[size_t(i)].camera;
    const at::Tensor u = c.fx * p.select(1, 0) / p.select(1, 2) + c.cx, w = c.fy * p.select(1, 1) / p.select(1, 2) + c.cy;
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

}  // namespace
}  // namespace sfgs::data
