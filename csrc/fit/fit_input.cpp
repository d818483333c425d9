#include "fit/fit_input.h"

#include <ATen/ATen.h>

#include <cstdio>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>

#include "data/colmap.h"
#include "data/dataset.h"
#include "data/image_io.h"
#include "data/json_values.h"
#include "body/wholebody_keypoints.h"
#include "data/keypoint_file.h"

namespace sfgs::fit {
namespace fs = std::filesystem;

namespace {

// A frame needs this many detected body keypoints (score > 0) for the fit to place the body at all: with fewer, the
// depth and rotation are free and the fit lands metres off.
constexpr int64_t kMinPlacingKeypoints = 4;
constexpr int64_t kFramesNamedInErrors = 8;

std::string padded(int64_t number, int digits) {
  char name[32];
  std::snprintf(name, sizeof(name), "%0*lld", digits, static_cast<long long>(number));
  return name;
}

int64_t frame_number_of(const std::string& image_name, const std::string& where) {
  const std::string stem = fs::path(image_name).stem().string();
  TORCH_CHECK(!stem.empty() && stem.find_first_not_of("0123456789") == std::string::npos, where, ": image '",
              image_name, "' is not named by a frame number like 00012.png");
  return std::stoll(stem);
}

// NeuMan's masks: SAM masks/<n>.png (person white), else segmentations/<n, 5 digits>.png (person black).
void find_neuman_mask(const fs::path& root, FitFrame& f) {
  const fs::path sam = root / "masks" / (std::to_string(f.number) + ".png");
  const fs::path segmentation = root / "segmentations" / (padded(f.number, 5) + ".png");
  if (fs::exists(sam)) {
    f.mask_path = sam.string();
  } else if (fs::exists(segmentation)) {
    f.mask_path = segmentation.string();
    f.mask_white_person = false;
  }
}

std::map<int64_t, FitFrame> frames_from_colmap(const fs::path& root, const std::map<int64_t, std::string>& keypoints,
                                               std::string& source) {
  const std::string cameras_path = (root / "sparse" / "cameras.txt").string();
  const auto cameras = data::read_colmap_cameras(cameras_path);
  const auto with = [](FitFrame f, const data::ColmapIntrinsics& c) {
    f.fx = c.fx, f.fy = c.fy, f.cx = c.cx, f.cy = c.cy, f.width = c.width, f.height = c.height;
    return f;
  };
  std::map<int64_t, FitFrame> frames;
  const fs::path images_path = root / "sparse" / "images.txt";
  if (!fs::exists(images_path)) {
    TORCH_CHECK(cameras.size() == 1, "'", cameras_path, "' defines ", cameras.size(),
                " cameras but there is no sparse/images.txt to say which frame uses which");
    for (const auto& [number, path] : keypoints) {
      FitFrame f;
      f.number = number;
      frames[number] = with(f, cameras.begin()->second);
    }
    source = cameras_path;
    return frames;
  }
  for (const data::ColmapImage& image : data::read_colmap_images(images_path.string())) {
    FitFrame f;
    f.number = frame_number_of(image.name, images_path.string());
    const auto camera = cameras.find(image.camera_id);
    TORCH_CHECK(camera != cameras.end(), "'", images_path.string(), "': image '", image.name, "' uses camera ",
                image.camera_id, " which '", cameras_path, "' does not define");
    frames[f.number] = with(f, camera->second);
  }
  source = cameras_path;
  return frames;
}

std::map<int64_t, FitFrame> frames_from_dataset(const std::string& folder, at::Tensor& betas) {
  const data::Dataset d = data::read_sfgs_dataset(folder);
  betas = d.betas;
  std::map<int64_t, FitFrame> frames;
  for (int64_t i = 0; i < d.size(); ++i) {
    const data::FrameRecord& r = d.frames[size_t(i)];
    FitFrame f;
    f.number = i;
    f.fx = r.camera.fx, f.fy = r.camera.fy, f.cx = r.camera.cx, f.cy = r.camera.cy;
    f.width = r.camera.width, f.height = r.camera.height;
    f.mask_path = r.mask_path;
    f.mask_white_person = r.mask_encoding == data::MaskEncoding::kWhitePerson;
    frames[i] = f;
  }
  return frames;
}

// A folder of frames only: each image's size gives the principal point and, unless given, the focal length.
std::map<int64_t, FitFrame> frames_from_images(const fs::path& root, const std::map<int64_t, std::string>& keypoints) {
  std::map<int64_t, FitFrame> frames;
  for (const auto& [number, path] : keypoints) {
    std::string image;
    for (const fs::path& candidate :
         {root / "images" / (padded(number, 5) + ".png"), root / "images" / (padded(number, 6) + ".png"),
          root / "images" / (std::to_string(number) + ".png"), root / "frames" / (std::to_string(number) + ".png"),
          root / "images" / (padded(number, 5) + ".jpg"), root / "frames" / (std::to_string(number) + ".jpg")})
      if (fs::exists(candidate)) {
        image = candidate.string();
        break;
      }
    TORCH_CHECK(!image.empty(), "'", root.string(),
                "' has neither sparse/cameras.txt nor dataset.json, and no image "
                "of frame ",
                number, " (images/", padded(number, 5), ".png or frames/", number,
                ".png) gives its size for the camera");
    FitFrame f;
    f.number = number;
    std::tie(f.width, f.height) = data::image_size(image);
    f.fx = f.fy = double(std::max(f.width, f.height));
    f.cx = f.width / 2.0;
    f.cy = f.height / 2.0;
    const fs::path mask = root / "masks" / (std::to_string(number) + ".png");
    if (fs::exists(mask)) f.mask_path = mask.string();
    frames[number] = f;
  }
  return frames;
}

}  // namespace

FitInput read_fit_input(const std::string& folder, double focal) {
  TORCH_CHECK(fs::is_directory(folder), "sfgs fit: data folder '", folder, "' does not exist");
  const fs::path root(folder);
  const std::map<int64_t, std::string> keypoint_files = data::list_keypoint_files(folder);
  FitInput in;
  in.folder = folder;
  std::map<int64_t, FitFrame> frames;
  if (fs::exists(root / "sparse" / "cameras.txt")) {
    frames = frames_from_colmap(root, keypoint_files, in.camera_source);
    for (auto& [number, f] : frames) find_neuman_mask(root, f);
    const fs::path shape = root / "smplx_optimized" / "shape_param.json";
    if (fs::exists(shape)) in.betas = data::json_numbers(data::read_json_file(shape.string()), {-1}, shape.string());
  } else if (fs::exists(root / "dataset.json")) {
    frames = frames_from_dataset(folder, in.betas);
    in.camera_source = (root / "dataset.json").string();
  } else {
    frames = frames_from_images(root, keypoint_files);
    in.camera_source = "the image size (focal length max(width, height), principal point at the centre)";
  }
  for (const auto& [number, f] : frames)
    TORCH_CHECK(keypoint_files.count(number), "sfgs fit: frame ", number, " of '", folder, "' has no keypoint file ",
                (root / data::kKeypointFolder / (std::to_string(number) + ".json")).string(),
                " (every frame needs its 133 whole-body keypoints)");
  for (const auto& [number, path] : keypoint_files)
    TORCH_CHECK(frames.count(number), "sfgs fit: keypoint file '", path, "' names frame ", number, ", which ",
                in.camera_source, " does not list");
  std::vector<at::Tensor> keypoints;
  const body::KeypointRange body_keypoints = body::keypoint_range(body::KeypointGroup::kBody);
  std::string unplaceable;  // frames with too few detected body keypoints, as "frame N (K)"
  int64_t unplaceable_count = 0;
  for (auto& [number, f] : frames) {
    if (focal > 0) f.fx = f.fy = focal;
    keypoints.push_back(data::read_wholebody_keypoints(keypoint_files.at(number)));
    const at::Tensor scores = keypoints.back().narrow(0, body_keypoints.begin, body_keypoints.size()).select(1, 2);
    const int64_t detected = (scores > 0).sum().item<int64_t>();
    if (detected < kMinPlacingKeypoints && unplaceable_count++ < kFramesNamedInErrors)
      unplaceable += (unplaceable.empty() ? "" : ", ") + ("frame " + std::to_string(number)) + " (" +
                     std::to_string(detected) + ")";
    in.frames.push_back(f);
  }
  TORCH_CHECK(unplaceable_count == 0, "sfgs fit: ", unplaceable_count, " of ", frames.size(), " frames of '", folder,
              "' have fewer than ", kMinPlacingKeypoints, " of the ", body_keypoints.size(),
              " body keypoints with a positive score, too few to place the body (", unplaceable,
              unplaceable_count > kFramesNamedInErrors ? ", ..." : "",
              "): run the detector on them again, or remove those frames (image, keypoint file and mask)");
  if (focal > 0) in.camera_source += " with the focal length given (" + std::to_string(focal) + " px)";
  in.keypoints = at::stack(keypoints);
  return in;
}

}  // namespace sfgs::fit
