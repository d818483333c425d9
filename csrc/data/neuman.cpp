#include "data/neuman.h"

#include <filesystem>
#include <fstream>
#include <set>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "data/colmap.h"
#include "data/json_values.h"
#include "data/keypoint_file.h"

namespace sfgs::data {
namespace fs = std::filesystem;

namespace {

// Frame times only matter relative to each other (they are normalised to [-1, 1]); NeuMan videos are 30 fps.
constexpr double kNeumanFramesPerSecond = 30.0;

int64_t frame_number(const std::string& image_name) {
  const std::string stem = fs::path(image_name).stem().string();
  TORCH_CHECK(!stem.empty() && stem.find_first_not_of("0123456789") == std::string::npos, "NeuMan image name '",
              image_name, "' is not a frame number like 00012.png");
  return std::stoll(stem);
}

std::set<std::string> split_names(const std::string& path) {
  std::set<std::string> names;
  std::ifstream in(path);
  if (!in.good()) return names;
  for (std::string line; std::getline(in, line);) {
    line.erase(line.find_last_not_of(" \t\r") + 1);
    if (!line.empty()) names.insert(line);
  }
  return names;
}

}  // namespace

SmplxPose read_exavatar_pose(const std::string& path) {
  const nlohmann::json j = read_json_file(path);
  const auto field = [&](const char* key, std::vector<int64_t> shape) {
    TORCH_CHECK(j.contains(key), "'", path, "' lacks the SMPL-X parameter '", key, "'");
    return json_numbers(j.at(key), shape, path + ": " + key);
  };
  SmplxPose p;
  p.global_orient = field("root_pose", {3});
  p.body_pose = field("body_pose", {21, 3});
  p.jaw_pose = field("jaw_pose", {3});
  p.leye_pose = field("leye_pose", {3});
  p.reye_pose = field("reye_pose", {3});
  p.left_hand_pose = field("lhand_pose", {15, 3});
  p.right_hand_pose = field("rhand_pose", {15, 3});
  p.expression = field("expr", {-1});
  p.transl = field("trans", {3});
  return p;
}

Dataset read_neuman(const std::string& folder) {
  const fs::path root(folder);
  const auto cameras = read_colmap_cameras((root / "sparse" / "cameras.txt").string());
  std::vector<ColmapImage> images = read_colmap_images((root / "sparse" / "images.txt").string());
  TORCH_CHECK(!images.empty(), "NeuMan folder '", folder, "': sparse/images.txt lists no image");
  std::sort(images.begin(), images.end(), [](const ColmapImage& a, const ColmapImage& b) { return a.name < b.name; });
  const fs::path params = root / "smplx_optimized";
  const std::string shape_path = (params / "shape_param.json").string();

  Dataset d;
  d.source = folder;
  d.format = "neuman";
  d.sequences = {root.filename().string()};
  d.betas = json_numbers(read_json_file(shape_path), {-1}, shape_path);
  // Exact fits beside corrupted ones (`sfgs synth --layout neuman --pose-noise`): ground_truth/ holds the files of
  // smplx_optimized/, read as the frames' true poses and the true shape (what refinement is measured against).
  const fs::path truth = root / "ground_truth";
  const bool has_truth = fs::is_directory(truth);
  if (has_truth) {
    const std::string truth_shape = (truth / "shape_param.json").string();
    d.true_betas = json_numbers(read_json_file(truth_shape), {-1}, truth_shape);
  }
  const std::set<std::string> train = split_names((root / "train_split.txt").string());
  const std::set<std::string> test = split_names((root / "test_split.txt").string());
  const std::set<std::string> val = split_names((root / "val_split.txt").string());  // optional
  TORCH_CHECK(!train.empty() || !test.empty(), "NeuMan folder '", folder,
              "' has no train_split.txt or test_split.txt (lines like 00012.png)");

  for (const ColmapImage& image : images) {
    const auto cam = cameras.find(image.camera_id);
    TORCH_CHECK(cam != cameras.end(), "NeuMan folder '", folder, "': image '", image.name, "' uses camera ",
                image.camera_id, " which sparse/cameras.txt does not define");
    const int64_t number = frame_number(image.name);
    FrameRecord r;
    r.name = fs::path(image.name).stem().string();
    r.time = double(number) / kNeumanFramesPerSecond;
    r.camera.world_to_camera = image.world_to_camera;
    r.camera.fx = cam->second.fx;
    r.camera.fy = cam->second.fy;
    r.camera.cx = cam->second.cx;
    r.camera.cy = cam->second.cy;
    r.camera.width = cam->second.width;
    r.camera.height = cam->second.height;
    r.image_path = (root / "images" / image.name).string();
    const fs::path sam_mask = root / "masks" / (std::to_string(number) + ".png");
    const fs::path segmentation = root / "segmentations" / image.name;
    TORCH_CHECK(fs::exists(sam_mask) || fs::exists(segmentation), "NeuMan folder '", folder, "': frame ", r.name,
                " has neither ", sam_mask.string(), " nor ", segmentation.string());
    if (fs::exists(sam_mask)) {
      r.mask_path = sam_mask.string();
      r.mask_encoding = MaskEncoding::kWhitePerson;
    } else {
      r.mask_path = segmentation.string();
      r.mask_encoding = MaskEncoding::kBlackPerson;
    }
    if (fs::exists(segmentation)) {
      r.eval_mask_path = segmentation.string();
      r.eval_mask_encoding = MaskEncoding::kBlackPerson;
    }
    const fs::path keypoints = root / kKeypointFolder / (std::to_string(number) + ".json");
    if (fs::exists(keypoints)) r.keypoints_path = keypoints.string();
    r.pose = read_exavatar_pose((params / "smplx_params" / (std::to_string(number) + ".json")).string());
    r.pose_in_camera_frame = true;  // ExAvatar fits each frame in its camera's coordinates
    if (has_truth)
      r.true_pose = read_exavatar_pose((truth / "smplx_params" / (std::to_string(number) + ".json")).string());
    const int64_t index = d.size();
    if (train.count(image.name)) d.splits[Split::kTrain].push_back(index);
    if (test.count(image.name)) d.splits[Split::kTest].push_back(index);
    if (val.count(image.name)) d.splits[Split::kVal].push_back(index);
    d.frames.push_back(std::move(r));
  }
  d.validate();
  return d;
}

}  // namespace sfgs::data
