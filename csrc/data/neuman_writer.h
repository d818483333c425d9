#pragma once
// Writing the NeuMan / ExAvatar layout that read_neuman reads (neuman.h): COLMAP's text cameras, the split files and
// the `smplx_optimized/` parameter folder (shape_param.json and smplx_params/<frame>.json in camera coordinates).
// `sfgs synth --layout neuman` writes whole sequences with it; `sfgs fit` writes its fits with it.
#include <ATen/core/Tensor.h>

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "body/smplx_pose.h"
#include "ops/splat/splat.h"

namespace sfgs::data {

// One frame's SMPL-X parameters as ExAvatar writes them (root_pose, body_pose, jaw_pose, leye_pose, reye_pose,
// lhand_pose, rhand_pose, expr, trans; nested triples; 7 significant digits).
std::string exavatar_pose_json(const body::SmplxPose& pose);

// SMPL-X parameters in world coordinates moved into a camera's coordinates [R | t]: the body turns about its rest
// pelvis `rest_pelvis` (3), so global_orient' = R global_orient and transl' = R (pelvis + transl) + t - pelvis.
body::SmplxPose pose_in_camera(const body::SmplxPose& world, const std::array<double, 16>& world_to_camera,
                               const at::Tensor& rest_pelvis);

// A `smplx_optimized/`-style folder written as one piece (common/atomic_file.h AtomicFolder): shape_param.json
// (`betas`), smplx_params/<frame>.json per pose, and `extra_files` (relative path -> text). An existing folder is
// replaced only when `overwrite`.
void write_smplx_parameter_folder(const std::string& folder, const at::Tensor& betas,
                                  const std::map<int64_t, body::SmplxPose>& poses,
                                  const std::map<std::string, std::string>& extra_files, bool overwrite);

struct ColmapFrame {
  std::string image_name;  // e.g. 00012.png
  Camera camera;
};

// sparse/cameras.txt (one PINHOLE camera per distinct intrinsics) and sparse/images.txt (each frame's world to
// camera as COLMAP's quaternion and translation) under `folder`, atomically.
void write_colmap_model(const std::string& folder, const std::vector<ColmapFrame>& frames, bool overwrite);

// A split file: one image name per line.
void write_split_file(const std::string& path, const std::vector<std::string>& image_names, bool overwrite);

}  // namespace sfgs::data
