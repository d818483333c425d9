#pragma once
// NeuMan sequences as ExAvatar preprocesses them: images/, masks/ (SAM, training), segmentations/ (evaluation),
// sparse/{cameras,images}.txt (COLMAP), smplx_optimized/ (per-frame SMPL-X in camera coordinates, shared shape) and
// train_split.txt / test_split.txt. docs/dataset_format.md lists the files read.
#include <string>

#include "data/dataset.h"

namespace sfgs::data {

Dataset read_neuman(const std::string& folder);

// One ExAvatar SMPL-X parameter file (root_pose, body_pose, jaw_pose, leye_pose, reye_pose, lhand_pose, rhand_pose,
// expr, trans); errors name the file and the key.
body::SmplxPose read_exavatar_pose(const std::string& path);

}  // namespace sfgs::data
