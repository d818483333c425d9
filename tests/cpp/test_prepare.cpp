// `sfgs prepare` as a library (prepare/prepare.h): a synthetic video's frames become a NeuMan-layout dataset with
// masks, whole-body keypoints, a camera and fits that read back as a trainable dataset; bad inputs are clear errors
// and leave nothing behind. Skipped without the MediaPipe models.
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <cstdint>
#include <utility>
#include <vector>
#include <fstream>
#include <cstring>
#include <string>
#include <stdexcept>
#include <optional>
#include <memory>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "common/atomic_file.h"
#include "data/dataset.h"
#include "data/keypoint_file.h"
#include "data/synthetic.h"
#include "detect/models.h"
#include "prepare/prepare.h"
#include "prepare/video_metadata.h"
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
  EXPECT_EQ(r.focal_source, "default");
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

// QuickTime atoms as bytes: a big-endian size, a type, a payload.
std::string atom(const std::string& type, const std::string& payload) {
  const uint32_t size = uint32_t(8 + payload.size());
  std::string out = {char(size >> 24), char(size >> 16), char(size >> 8), char(size)};
  return out + type + payload;
}

std::string be32(uint32_t v) { return {char(v >> 24), char(v >> 16), char(v >> 8), char(v)}; }

// A `meta` atom with two items, as an iPhone writes them: the lens as text and the focal length as `value` of
// well-known type `type`.
std::string meta_atom(uint32_t type, const std::string& value, bool iso_full_box) {
  const std::string lens = "com.apple.quicktime.camera.lens_model",
                    focal = "com.apple.quicktime.camera.focal_length.35mm_equivalent";
  const std::string keys = atom("keys", be32(0) + be32(2) + be32(uint32_t(8 + lens.size())) + "mdta" + lens +
                                            be32(uint32_t(8 + focal.size())) + "mdta" + focal);
  const std::string items =
      atom("ilst", atom(be32(1), atom("data", be32(1) + be32(0) + "iPhone back camera 5.7mm f/1.5")) +
                       atom(be32(2), atom("data", be32(type) + be32(0) + value)));
  const std::string hdlr = atom("hdlr", std::string(8, '\0') + "mdta" + std::string(12, '\0'));
  return atom("meta", (iso_full_box ? be32(0) : "") + hdlr + keys + items);
}

std::string write_movie(const std::string& name, const std::string& bytes) {
  const std::string path = (fs::temp_directory_path() / (name + std::to_string(::getpid()))).string();
  std::ofstream(path, std::ios::binary) << bytes;
  return path;
}

// The 35 mm-equivalent focal length from a movie's metadata, whatever the atom's place and the value's type; none
// where there is none or the file is not a movie; and the pixel focal length it gives.
TEST(Prepare, TheLensComesFromAVideosMetadata) {
  const std::string ftyp = atom("ftyp", "qt  " + be32(0) + "qt  "), mdat = atom("mdat", std::string(64, 'x'));
  // A 64-bit sized media atom before the movie: the reader skips it by its header.
  const std::string large_mdat = be32(1) + "mdat" + std::string(4, '\0') + be32(16 + 32) + std::string(32, 'y');
  const auto movie = [&](const std::string& meta, const std::string& where) {
    const std::string track = atom("trak", atom("tkhd", std::string(84, '\0')) + (where == "trak" ? meta : ""));
    return ftyp + large_mdat +
           atom("moov", atom("mvhd", std::string(100, '\0')) + track + (where == "udta" ? atom("udta", meta) : "") +
                            (where == "moov" ? meta : "")) +
           mdat;
  };
  struct Case {
    const char* name;
    std::string bytes;
    std::optional<double> expected;
  };
  const float f = 26.5f;
  uint32_t float_bits;
  std::memcpy(&float_bits, &f, 4);
  const std::vector<Case> cases = {
      {"a signed integer in the track's meta", movie(meta_atom(21, std::string("\0\x1a", 2), false), "trak"), 26.0},
      {"a float in the movie's meta", movie(meta_atom(23, be32(float_bits), false), "moov"), 26.5},
      {"text in the user data's ISO meta", movie(meta_atom(1, "50.00mm", true), "udta"), 50.0},
      {"a value outside any lens", movie(meta_atom(21, be32(2000), false), "trak"), std::nullopt},
      {"no metadata", movie("", "moov"), std::nullopt},
      {"not a movie", std::string("\x89PNG\r\n\x1a\n and more bytes"), std::nullopt},
      {"a truncated movie", movie(meta_atom(21, be32(26), false), "trak").substr(0, 180), std::nullopt},
      // A 64-bit size that would send the reader back to an earlier atom, or past the file's end.
      {"an atom larger than the file", ftyp + be32(1) + "free" + std::string(8, '\xff') + mdat, std::nullopt},
  };
  for (const Case& c : cases) {
    const std::string path = write_movie("sfgs_movie_", c.bytes);
    const std::optional<double> read = prepare::focal_length_35mm(path);
    fs::remove(path);
    ASSERT_EQ(read.has_value(), c.expected.has_value()) << c.name;
    if (read) EXPECT_DOUBLE_EQ(*read, *c.expected) << c.name;
  }
  EXPECT_FALSE(prepare::focal_length_35mm("/nonexistent/clip.mov").has_value());
  // 26 mm equivalent on a 1080 x 1920 picture: 26 / 43.27 of its 2,202.9-pixel diagonal.
  EXPECT_NEAR(prepare::focal_pixels_from_35mm(26, 1080, 1920), 1323.7, 0.1);
}

// The camera's focal length: --focal when given, else the video's lens, else the default.
TEST(Prepare, TheFocalLengthIsTheGivenOneElseTheVideosElseTheDefault) {
  SFGS_SKIP_WITHOUT_MEDIAPIPE_MODELS();
  const fs::path root = fs::temp_directory_path() / ("sfgs_prepare_focal_" + std::to_string(::getpid()));
  data::SyntheticVideoOptions v;
  v.motions = {"walk"};
  v.frames = 1;
  v.width = 180;
  v.height = 320;
  v.overwrite = true;
  data::write_synthetic_video((root / "video").string(), v);
  const auto focal_of = [&](double focal, double focal_35mm) {
    prepare::PrepareOptions o;
    o.out = (root / "dataset").string();
    o.overwrite = o.quiet = true;
    o.fit = false;
    o.focal = focal;
    o.focal_35mm = focal_35mm;
    const prepare::PrepareReport r =
        prepare::prepare_dataset(prepare::image_folder((root / "video" / "images").string()), o);
    return std::pair(r.focal, r.focal_source);
  };
  const auto [metadata, from_metadata] = focal_of(0, 26);
  EXPECT_NEAR(metadata, 26 / 43.27 * std::hypot(180.0, 320.0), 1e-9);
  EXPECT_EQ(from_metadata, "metadata");
  EXPECT_EQ(focal_of(300, 26), std::pair(300.0, std::string("given")));
  EXPECT_EQ(focal_of(0, 0), std::pair(320.0, std::string("default")));
  remove_tree(root.string());
}

}  // namespace
}  // namespace sfgs::testing
