#include "data/synthetic_layouts.h"

#include <ATen/ATen.h>

#include <cstdio>
#include <filesystem>
#include <map>

#include "data/keypoint_file.h"
#include "data/neuman_writer.h"

namespace sfgs::data {
namespace fs = std::filesystem;

namespace {

constexpr const char* kGroundTruthFolder = "ground_truth";
constexpr const char* kFitsFolder = "smplx_optimized";

std::string numbered(const char* format, int64_t index) {
  char name[32];  // room for any int64
  std::snprintf(name, sizeof(name), format, static_cast<long long>(index));
  return name;
}

// The hand poses of an absolute pose made relative to the model's mean hand: how ExAvatar's fits and both layouts
// store them, and how the avatar reads them by default (flat_hand_mean false, which adds the mean back).
body::SmplxPose hands_relative_to_mean(body::SmplxPose p, const SyntheticVideo& video) {
  p.left_hand_pose = p.left_hand_pose - video.hands_mean_left.to(p.left_hand_pose.scalar_type()).view({-1, 3});
  p.right_hand_pose = p.right_hand_pose - video.hands_mean_right.to(p.right_hand_pose.scalar_type()).view({-1, 3});
  return p;
}

// ExAvatar's convention: camera coordinates, hand poses relative to the mean hand.
std::map<int64_t, body::SmplxPose> exavatar_fits(const SyntheticVideo& video, bool exact) {
  std::map<int64_t, body::SmplxPose> fits;
  for (size_t i = 0; i < video.frames.size(); ++i) {
    const FrameRecord& r = video.frames[i];
    const bool use_truth = exact && r.true_pose.has_value();
    const at::Tensor& pelvis = (use_truth ? video.true_rest_pelvis : video.rest_pelvis)[int64_t(i)];
    fits[int64_t(i)] = hands_relative_to_mean(
        pose_in_camera(use_truth ? *r.true_pose : r.pose, r.camera.world_to_camera, pelvis), video);
  }
  return fits;
}

}  // namespace

SyntheticFramePaths synthetic_frame_paths(const std::string& folder, DatasetLayout layout, int64_t index) {
  const fs::path root(folder);
  SyntheticFramePaths p;
  p.keypoints = (root / kKeypointFolder / (std::to_string(index) + ".json")).string();
  if (layout == DatasetLayout::kSfgs) {
    const std::string name = numbered("%06lld", index);
    p.image = (root / "images" / (name + ".png")).string();
    p.mask = (root / "masks" / (name + ".png")).string();
    p.mesh = (root / "meshes" / (name + ".npy")).string();
  } else {
    p.image = (root / "images" / (numbered("%05lld", index) + ".png")).string();
    p.mask = (root / "masks" / (std::to_string(index) + ".png")).string();
  }
  return p;
}

void write_sfgs_layout_index(const std::string& folder, const SyntheticVideo& video, bool overwrite) {
  Dataset d;
  d.source = folder;
  d.format = "sfgs";
  d.sequences = video.sequences;
  d.betas = video.betas;
  d.true_betas = video.true_betas;
  d.frames = video.frames;
  for (FrameRecord& r : d.frames) {
    r.pose = hands_relative_to_mean(r.pose, video);
    if (r.true_pose) r.true_pose = hands_relative_to_mean(*r.true_pose, video);
  }
  d.splits = video.splits;
  write_sfgs_dataset(d, folder, overwrite);
}

void write_neuman_layout_index(const std::string& folder, const SyntheticVideo& video, bool overwrite) {
  std::vector<ColmapFrame> cameras;
  for (size_t i = 0; i < video.frames.size(); ++i)
    cameras.push_back({numbered("%05lld", int64_t(i)) + ".png", video.frames[i].camera});
  write_colmap_model(folder, cameras, overwrite);
  for (const auto& [split, file] :
       {std::make_pair(Split::kTrain, "train_split.txt"), std::make_pair(Split::kVal, "val_split.txt"),
        std::make_pair(Split::kTest, "test_split.txt")}) {
    std::vector<std::string> names;
    const auto it = video.splits.find(split);
    if (it != video.splits.end())
      for (int64_t i : it->second) names.push_back(cameras[size_t(i)].image_name);
    write_split_file((fs::path(folder) / file).string(), names, overwrite);
  }
  const at::Tensor true_betas = video.true_betas.defined() ? video.true_betas : video.betas;
  write_smplx_parameter_folder((fs::path(folder) / kFitsFolder).string(), video.betas, exavatar_fits(video, false), {},
                               overwrite);
  write_smplx_parameter_folder((fs::path(folder) / kGroundTruthFolder).string(), true_betas, exavatar_fits(video, true),
                               {}, overwrite);
}

}  // namespace sfgs::data
