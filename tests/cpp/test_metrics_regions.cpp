// Where the error is: the SSIM map the region metrics average, the region masks of a mesh whose labelling is known
// pixel by pixel, region PSNR/SSIM against the plain metrics on the selected pixels, and the region files' errors.
#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "train/constants.h"
#include "io/npz.h"
#include "metrics/image_metrics.h"
#include "test_files.h"
#include "train/region_metrics.h"
#include "test_metrics_support.h"

namespace sfgs::testing {
namespace {

using metrics::SsimBorder;

TEST(MetricsRegions, SsimMapAveragesToSsimInEveryBorderMode) {
  const at::Tensor x = random_image(21, 25, 1), y = (x + 0.3 * random_image(21, 25, 2)).clamp(0, 1);
  for (SsimBorder border : {SsimBorder::valid, SsimBorder::zero, SsimBorder::reflect}) {
    const at::Tensor map = metrics::ssim_map(x, y, border);
    const int64_t crop = border == SsimBorder::valid ? 10 : 0;
    ASSERT_EQ(map.sizes(), at::IntArrayRef({21 - crop, 25 - crop})) << int(border);
    EXPECT_NEAR(map.mean().item<double>(), metrics::ssim(x, y, border).item<double>(), 1e-14) << int(border);
  }
}

// A 40 x 40 image: a region mask covering the left half, another a 3 x 3 patch (below kMinRegionPixels).
TEST(MetricsRegions, RegionPsnrIsThePsnrOfTheRegionsPixelsAndTinyRegionsDoNotCount) {
  const int64_t side = 40;
  const at::Tensor target = random_image(side, side, 3);
  at::Tensor prediction = target.clone();
  prediction.slice(1, 0, side / 2) += 0.05;  // the left half is off by 0.05 in every channel: MSE 0.0025
  const at::Tensor left = at::zeros({side, side}, at::kBool), patch = at::zeros({side, side}, at::kBool);
  left.slice(1, 0, side / 2).fill_(true);
  patch.slice(0, 0, 3).slice(1, 30, 33).fill_(true);
  const at::Tensor right = left.logical_not();
  train::RegionAccumulator accumulator(SsimBorder::zero);
  accumulator.add(prediction, target, {{"left", left}, {"right", right}, {"patch", patch}});
  accumulator.add(prediction, target, {{"left", left}, {"right", right}, {"patch", patch}});
  const std::vector<train::GroupScore> scores = accumulator.summary();
  ASSERT_EQ(scores.size(), 3u);
  EXPECT_EQ(scores[0].name, "left");
  EXPECT_EQ(scores[0].frames, 2);
  EXPECT_DOUBLE_EQ(scores[0].pixels, double(side * side / 2));
  EXPECT_NEAR(scores[0].psnr, 10.0 * std::log10(1.0 / 0.0025), 1e-9);
  // Untouched pixels: the PSNR is capped by kMinRegionMse, not infinite.
  EXPECT_NEAR(scores[1].psnr, 10.0 * std::log10(1.0 / kMinRegionMse), 1e-9);
  // The right half's SSIM windows away from the seam see identical images: the region's SSIM is near 1 and above
  // the left half's.
  const at::Tensor map = metrics::ssim_map(prediction, target, SsimBorder::zero);
  EXPECT_NEAR(scores[1].ssim, map.masked_select(right).mean().item<double>(), 1e-12);
  EXPECT_NEAR(scores[0].ssim, map.masked_select(left).mean().item<double>(), 1e-12);
  EXPECT_GT(scores[1].ssim, scores[0].ssim);
  EXPECT_EQ(scores[2].frames, 0) << "9 pixels are fewer than kMinRegionPixels";
  // The bias: +0.05 in every channel on the left, none on the right (float32 arithmetic on the offset).
  for (size_t c = 0; c < 3; ++c) {
    EXPECT_NEAR(scores[0].signed_error[c], 0.05, 1e-6) << c;
    EXPECT_EQ(scores[1].signed_error[c], 0.0) << c;
  }
}

// Two triangles making a square in front of the camera, split along its diagonal: the first is body and seen, the
// second face and unseen.
struct TwoTriangles {
  at::Tensor vertices =
      at::tensor({-1.0, -1.0, 0.0, 1.0, -1.0, 0.0, 1.0, 1.0, 0.0, -1.0, 1.0, 0.0}, at::kDouble).view({4, 3});
  train::RegionTruth truth;
  Camera camera = Camera::looking_forward(40.0, 64, 64);
  TwoTriangles() {
    truth.faces = at::tensor({0, 1, 2, 0, 2, 3}, at::kLong).view({2, 3});
    truth.face_region = at::tensor({0, 1}, at::kLong);
    truth.face_seen = at::tensor({1, 0}, at::kLong).to(at::kBool);
    camera.world_to_camera = {1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 5, 0, 0, 0, 1};  // at (0, 0, 5) looking down -z
  }
};

TEST(MetricsRegions, MasksLabelEachPixelByItsVisibleTriangle) {
  const TwoTriangles scene;
  at::Tensor eval_mask = at::ones({64, 64}, at::kFloat);
  eval_mask.slice(0, 0, 32).zero_();  // the evaluation ignores the top half of the image
  const auto masks = train::region_masks(scene.truth, scene.vertices, scene.camera, eval_mask);
  ASSERT_EQ(masks.size(), 5u);
  const auto mask = [&](const std::string& name) {
    for (const auto& [n, m] : masks)
      if (n == name) return m;
    ADD_FAILURE() << "no mask " << name;
    return at::Tensor();
  };
  EXPECT_TRUE(mask("body").equal(mask("seen")));
  EXPECT_TRUE(mask("face").equal(mask("unseen")));
  EXPECT_EQ(mask("hands").sum().item<int64_t>(), 0);
  EXPECT_EQ((mask("body") & mask("face")).sum().item<int64_t>(), 0) << "a pixel belongs to one triangle";
  EXPECT_EQ(mask("body").slice(0, 0, 32).sum().item<int64_t>() + mask("face").slice(0, 0, 32).sum().item<int64_t>(), 0)
      << "outside the evaluation mask nothing counts";
  // The square covers the 16 x 16 pixel centres around the image centre (x, y in [-1, 1] at distance 5, focal 40:
  // column = 8x + 32, row = 32 - 8y); the first triangle is where x > y. Row 38, column 38 (x = 0.81, y = -0.81) is
  // body; row 33, column 26 (x = -0.69, y = -0.19) is face.
  EXPECT_TRUE(mask("body")[38][38].item<bool>());
  EXPECT_TRUE(mask("face")[33][26].item<bool>());
  const int64_t covered = mask("body").sum().item<int64_t>() + mask("face").sum().item<int64_t>();
  EXPECT_EQ(covered, 16 * 8) << "the lower half of the 16 x 16 square";
}

TEST(MetricsRegions, UnseenShareIsTheUnseenPixelsOverTheLabelledOnes) {
  // Body is the seen triangle and face the unseen one: the body region is 0 % unseen, the face 100 %, and the person
  // (a motion) the face's share of the square's pixels, summed over the frames.
  const TwoTriangles scene;
  at::Tensor eval_mask = at::ones({64, 64}, at::kFloat);
  eval_mask.slice(0, 0, 32).zero_();
  const auto masks = train::region_masks(scene.truth, scene.vertices, scene.camera, eval_mask);
  const at::Tensor image = at::full({64, 64, 3}, 0.5, at::kDouble);
  train::RegionAccumulator accumulator(SsimBorder::zero);
  train::UnseenCount person;
  for (int frame = 0; frame < 2; ++frame) {
    accumulator.add(image, image, masks);
    person.add(train::labelled_person(masks), train::region_mask(masks, "unseen"));
  }
  const double face = double(train::region_mask(masks, "face").sum().item<int64_t>());
  const double body = double(train::region_mask(masks, "body").sum().item<int64_t>());
  ASSERT_GT(face, 0);
  ASSERT_GT(body, 0);
  ASSERT_TRUE(person.share().has_value());
  EXPECT_DOUBLE_EQ(*person.share(), face / (face + body));
  for (const train::GroupScore& g : accumulator.summary()) {
    if (g.name == "body" || g.name == "face") {
      ASSERT_TRUE(g.unseen_share.has_value()) << g.name;
      EXPECT_EQ(*g.unseen_share, g.name == "face" ? 1.0 : 0.0) << g.name;
    } else if (g.name == "hands") {
      EXPECT_FALSE(g.unseen_share.has_value()) << "no hand pixel: no share";
    } else {
      EXPECT_FALSE(g.unseen_share.has_value()) << g.name << " is an observation class, not a body region";
    }
  }
  EXPECT_FALSE(train::UnseenCount().share().has_value());
  expect_error_mentioning([&] { train::region_mask(masks, "elbow"); }, "elbow");
}

TEST(MetricsRegions, RegionFilesOfTheWrongKindAreErrorsNamingTheFile) {
  TempFolder folder;
  data::Dataset dataset;
  dataset.frames.resize(1);
  EXPECT_FALSE(train::read_region_truth(dataset).has_value()) << "no ground-truth mesh: no regions";
  dataset.frames[0].mesh_path = folder / "meshes/frame.npy";
  io::write_npy(folder / "meshes/faces.npy", at::tensor({0, 1, 2}, at::kLong).view({1, 3}), false);
  io::write_npy(folder / "meshes/regions.npy", at::tensor({0, 1, 1}, at::kLong), false);
  EXPECT_FALSE(train::read_region_truth(dataset).has_value()) << "observation.npy missing: no regions";
  io::write_npy(folder / "meshes/observation.npy", at::tensor({0.5f, 0.0f, 1.0f}), false);
  const std::optional<train::RegionTruth> truth = train::read_region_truth(dataset);
  ASSERT_TRUE(truth.has_value());
  EXPECT_EQ(truth->face_region.item<int64_t>(), 1) << "two of three corners are face";
  EXPECT_FALSE(truth->face_seen.item<bool>()) << "one corner was never seen";
  io::write_npy(folder / "meshes/observation.npy", at::tensor({0.5, 0.0, 1.0}, at::kDouble), true);
  expect_error_mentioning([&] { train::read_region_truth(dataset); }, "observation.npy");
  io::write_npy(folder / "meshes/observation.npy", at::tensor({0.5f, 0.0f}), true);
  expect_error_mentioning([&] { train::read_region_truth(dataset); }, "observation.npy");
  io::write_npy(folder / "meshes/observation.npy", at::tensor({0.5f, 0.0f, 1.0f}), true);
  io::write_npy(folder / "meshes/faces.npy", at::tensor({0, 1, 7}, at::kLong).view({1, 3}), true);
  expect_error_mentioning([&] { train::read_region_truth(dataset); }, "faces.npy");
}

}  // namespace
}  // namespace sfgs::testing
