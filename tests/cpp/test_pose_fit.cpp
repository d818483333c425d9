// What a pose fit compares (train/pose_fit.h): the crop around the person holds the person with its margin, on every
// stage's pixel grid, in sizes of kPoseFitCropStep; and a fit on the crop minimises the whole image's objective.
// (Fitting itself: test_pose_refinement.cpp; recorded evaluations: tests/cuda/test_pose_fit_cuda.cpp.)
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "train/constants.h"
#include "test_avatar_utils.h"
#include "test_body_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/pose_fit.h"
#include "train/pose_fit_evaluation.h"

namespace sfgs::testing {
namespace {

using train::kCorrectionWidth;

void expect_on_grid_inside(const train::PixelBox& box, const at::Tensor& mask) {
  EXPECT_GE(box.x, 0);
  EXPECT_GE(box.y, 0);
  EXPECT_LE(box.x + box.width, mask.size(1));
  EXPECT_LE(box.y + box.height, mask.size(0));
  EXPECT_EQ(box.x % kPoseFitCoarseDownsample, 0) << "on the coarse stage's grid";
  EXPECT_EQ(box.y % kPoseFitCoarseDownsample, 0) << "on the coarse stage's grid";
  EXPECT_TRUE(box.width % kPoseFitCropStep == 0 || box.width == mask.size(1)) << box.width;
  EXPECT_TRUE(box.height % kPoseFitCropStep == 0 || box.height == mask.size(0)) << box.height;
}

TEST(TrainPoseFitting, PersonCropHoldsThePersonAndItsMarginOnTheStagesGrid) {
  // A person of 100 x 50 pixels: a margin of 15 each way, the crop narrower and lower than the image.
  at::Tensor mask = at::zeros({480, 640});
  mask.narrow(0, 101, 100).narrow(1, 303, 50).fill_(1);
  mask[300][10] = 0.4;  // below half: not the person
  const train::PixelBox box = train::person_crop(mask);
  expect_on_grid_inside(box, mask);
  EXPECT_LE(box.x, 303 - 15);
  EXPECT_GE(box.x + box.width, 353 + 15);
  EXPECT_LE(box.y, 101 - 15);
  EXPECT_GE(box.y + box.height, 201 + 15);
  EXPECT_LT(box.width, 640);
  EXPECT_LT(box.height, 480);

  // At the image's edge the crop stays inside; an axis the rounded crop would cover is kept whole.
  at::Tensor edge = at::zeros({480, 640});
  edge.narrow(0, 0, 400).narrow(1, 0, 21).fill_(1);
  const train::PixelBox edge_box = train::person_crop(edge);
  expect_on_grid_inside(edge_box, edge);
  EXPECT_EQ(edge_box.x, 0);
  EXPECT_GE(edge_box.width, 21 + 60);
  EXPECT_EQ(edge_box.y, 0);
  EXPECT_EQ(edge_box.height, 480);

  // No person: the whole image.
  const train::PixelBox empty = train::person_crop(at::zeros({48, 64}));
  EXPECT_EQ(empty.x, 0);
  EXPECT_EQ(empty.y, 0);
  EXPECT_EQ(empty.width, 64);
  EXPECT_EQ(empty.height, 48);
  expect_error([&] { train::person_crop(at::zeros({48, 64, 1})); }, {"(H, W)", "[48, 64, 1]"});
}

// The fit's start loss (on the crop, scaled by its pixel share) is the fine stage's objective over the whole image:
// the pixels the crop leaves out are white in both and transparent, whatever the misplacement within the margin.
TEST(TrainPoseFitting, ACroppedFitHasTheWholeImagesObjective) {
  TempFolder folder;
  data::Dataset dataset = tiny_video(folder, 10, 256);
  const int64_t f = dataset.split(data::Split::kTest)[0];
  model::Avatar avatar = render_frames_with_avatar(dataset, {f});
  const data::FrameRecord& record = dataset.frames[size_t(f)];
  const train::PoseFitTarget target = train::pose_fit_target(dataset, f, at::kCPU, false);
  const train::PixelBox box = train::person_crop(target.mask);
  ASSERT_LT(box.width * box.height, 256 * 256) << "the person fills part of the image";

  train::PoseFitOptions options;
  options.iterations = 1;  // the start's evaluation and one more
  options.loss.use_lpips = false;
  train::PoseFitter fitter(options, at::kCPU, nullptr);
  // Turned 0.05 rad and shifted 2 cm: a few pixels, within the margin.
  at::Tensor start = at::zeros({kCorrectionWidth});
  start[1] = 0.05;
  start[kCorrectionWidth - 3] = 0.02;
  const double cropped = fitter.fit(avatar, record.pose, target, start).start_loss;

  const train::ImageLoss image_loss(options.loss, at::kCPU);
  const train::FitLoss loss(image_loss, nullptr, 0);
  const train::FitFrame whole = train::fit_frame(avatar, record.pose, target, false);
  ASSERT_EQ(whole.pixel_share, 1.0);
  ASSERT_EQ(whole.image.size(1), 256);
  at::NoGradGuard no_grad;
  const double expected = loss(avatar, whole, start, true).item<double>();
  EXPECT_GT(expected, 0);
  EXPECT_NEAR(cropped, expected, 1e-4 * expected);
}

}  // namespace
}  // namespace sfgs::testing
