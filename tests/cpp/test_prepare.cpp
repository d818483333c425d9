// `sfgs prepare` as a library (prepare/prepare.h): a synthetic video's frames become a NeuMan-layout dataset with
// masks, whole-body keypoints, a camera and fits that read back as a trainable dataset; bad inputs are clear errors
// and leave nothing behind. Skipped without the MediaPipe models.
#include <unistd.h>

#include <filesystem>
#include <string>
#include <stdexcept>
#include <optional>
#include <memory>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "data/dataset.h"
#include "data/keypoint_file.h"
#include "data/synthetic.h"
#include "detect/models.h"
#include "prepare/prepare.h"
#include "test_body_utils.h"
#include "test_detect_utils.h"

namespace sfgs::testing {
namespace {
namespace fs = std::filesystem;

fs::path scratch(const std::string& name) {
  const fs::path p = fs::temp_directory_path() / ("sfgs_prepare_" + name + "_" + std::to_string(::getpid()));
  fs::remove_all(p);
  return p;
}

TEST(Prepare, AVideosFramesBecomeATrainableDataset) {
  SFGS_SKIP_WITHOUT_MEDIAPIPE_MODELS();
  const fs::path root = scratch("video");
  data::SyntheticVideoOptions v;
  v.motions = {"walk"};
  v.frames = 6;
  v.width = 180;
  v.height = 320;
  data::write_synthetic_video((root / "video").string(), v);
  prepare::PrepareOptions o;
  o.out = (root / "dataset").string();
  o.quiet = true;
  o.fit_options.iterations = {10, 20, 10, 5};
  const prepare::PrepareReport r =
      prepare::prepare_dataset(prepare::image_folder((root / "video" / "images").string()), o);
  EXPECT_EQ(r.frames, 6);
  EXPECT_EQ(r.frames_with_person, 6);
  EXPECT_EQ(r.width, 180);
  EXPECT_DOUBLE_EQ(r.focal, 320.0);
  ASSERT_TRUE(r.fit.has_value());
  EXPECT_TRUE(r.fit->trainable_dataset);
  const at::Tensor keypoints =
      data::read_wholebody_keypoints((root / "dataset" / "keypoints_whole_body" / "0.json").string());
  EXPECT_EQ(keypoints.size(0), 133);
  EXPECT_GT(keypoints.slice(0, 5, 17).select(1, 2).min().item<double>(), 0.5) << "the limbs are seen";
  const at::Tensor scored = keypoints.index_select(0, at::nonzero(keypoints.select(1, 2) > 0).view({-1}));
  EXPECT_LE(keypoints.select(1, 2).max().item<double>(), 1.0);
  EXPECT_TRUE((scored.select(1, 0) >= 0).all().item<bool>() && (scored.select(1, 0) <= 180).all().item<bool>() &&
              (scored.select(1, 1) >= 0).all().item<bool>() && (scored.select(1, 1) <= 320).all().item<bool>())
      << "every reported point lies in the image";
  const data::Dataset d = data::read_dataset((root / "dataset").string());
  EXPECT_EQ(d.size(), 6);
  EXPECT_FALSE(d.split(data::Split::kTrain).empty());
  for (const auto& entry : fs::directory_iterator(root))
    EXPECT_EQ(entry.path().string().find(".tmp"), std::string::npos) << "left behind: " << entry.path();
  // An existing dataset is kept unless overwriting is asked for.
  expect_error([&] { prepare::prepare_dataset(prepare::image_folder((root / "video" / "images").string()), o); },
               {"exists", "--force"});
  fs::remove_all(root);
}

TEST(Prepare, InputsWithoutAPersonAreClearErrorsAndLeaveNothing) {
  SFGS_SKIP_WITHOUT_MEDIAPIPE_MODELS();
  const fs::path root = scratch("empty");
  int served = 0;
  const prepare::FrameSource blank = [&]() -> std::optional<at::Tensor> {
    if (served++ == 3) return std::nullopt;
    return at::ones({120, 90, 3});
  };
  prepare::PrepareOptions o;
  o.out = (root / "dataset").string();
  o.quiet = true;
  expect_error([&] { prepare::prepare_dataset(blank, o); }, {"no person was found in any of the 3 frames"});
  EXPECT_FALSE(fs::exists(root / "dataset"));
  fs::create_directories(root);
  for (const auto& entry : fs::directory_iterator(root)) ADD_FAILURE() << "left behind: " << entry.path();
  expect_error([&] { prepare::image_folder((root / "nothing").string()); }, {"is neither a video nor a folder"});
  expect_error([&] { prepare::image_folder(root.string()); }, {"holds no .png or .jpg images"});
  fs::remove_all(root);
}

// Frames read ahead on another thread come in the source's order; an error of the source comes at the frame where it
// happened, after the frames before it; a reader dropped before the end stops without waiting for the rest.
TEST(Prepare, FramesReadAheadKeepTheirOrderAndTheSourcesError) {
  const auto counting = [](int64_t count, int64_t failing) {
    auto next = std::make_shared<int64_t>(0);
    return prepare::FrameSource([=]() -> std::optional<at::Tensor> {
      if (*next == failing) throw std::runtime_error("frame " + std::to_string(*next) + " is damaged");
      if (*next >= count) return std::nullopt;
      return at::full({2, 2, 3}, double((*next)++));
    });
  };
  prepare::FrameSource frames = prepare::read_ahead(counting(7, -1), 3);
  for (int64_t k = 0; k < 7; ++k) {
    const std::optional<at::Tensor> frame = frames();
    ASSERT_TRUE(frame.has_value()) << "frame " << k;
    EXPECT_EQ((*frame)[0][0][0].item<double>(), double(k));
  }
  EXPECT_FALSE(frames().has_value());
  EXPECT_FALSE(frames().has_value()) << "the end stays the end";

  prepare::FrameSource failing = prepare::read_ahead(counting(7, 3), 2);
  for (int64_t k = 0; k < 3; ++k) EXPECT_TRUE(failing().has_value());
  EXPECT_THROW(
      {
        try {
          failing();
        } catch (const std::runtime_error& e) {
          EXPECT_STREQ(e.what(), "frame 3 is damaged");
          throw;
        }
      },
      std::runtime_error);

  prepare::FrameSource dropped = prepare::read_ahead(counting(1000000, -1), 2);
  EXPECT_TRUE(dropped().has_value());
  dropped = nullptr;  // joins the reader, which is waiting for room
}

}  // namespace
}  // namespace sfgs::testing
