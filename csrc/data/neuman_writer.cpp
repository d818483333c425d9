#include "data/neuman_writer.h"

#include <ATen/ATen.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <tuple>

#include "body/rotations.h"
#include "common/atomic_file.h"

namespace sfgs::data {
namespace fs = std::filesystem;

namespace {

std::vector<unsigned char> bytes_of(const std::string& text) { return {text.begin(), text.end()}; }

// Values rounded to 7 significant digits, as nested triples when `triples` (ExAvatar's (n, 3) arrays).
nlohmann::json numbers(const at::Tensor& t, bool triples) {
  const at::Tensor flat = t.detach().to(at::kCPU, at::kDouble).contiguous().view({-1});
  const double* p = flat.data_ptr<double>();
  const auto rounded = [](double v) {
    char text[32];
    std::snprintf(text, sizeof(text), "%.7g", v);
    return std::strtod(text, nullptr);
  };
  nlohmann::json out = nlohmann::json::array();
  if (!triples) {
    for (int64_t i = 0; i < flat.numel(); ++i) out.push_back(rounded(p[i]));
    return out;
  }
  for (int64_t i = 0; i + 2 < flat.numel(); i += 3)
    out.push_back({rounded(p[i]), rounded(p[i + 1]), rounded(p[i + 2])});
  return out;
}

at::Tensor rotation_of(const std::array<double, 16>& m) {
  return at::tensor(std::vector<double>{m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]}, at::kDouble)
      .view({3, 3});
}

// COLMAP's (w, x, y, z) quaternion of a rotation matrix (row-major 3x3 inside the 4x4).
std::array<double, 4> quaternion_of(const std::array<double, 16>& m) {
  const double r00 = m[0], r01 = m[1], r02 = m[2], r10 = m[4], r11 = m[5], r12 = m[6], r20 = m[8], r21 = m[9],
               r22 = m[10];
  const double trace = r00 + r11 + r22;
  std::array<double, 4> q{};
  if (trace > 0) {
    const double s = 2 * std::sqrt(trace + 1);
    q = {s / 4, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s};
  } else if (r00 > r11 && r00 > r22) {
    const double s = 2 * std::sqrt(1 + r00 - r11 - r22);
    q = {(r21 - r12) / s, s / 4, (r01 + r10) / s, (r02 + r20) / s};
  } else if (r11 > r22) {
    const double s = 2 * std::sqrt(1 + r11 - r00 - r22);
    q = {(r02 - r20) / s, (r01 + r10) / s, s / 4, (r12 + r21) / s};
  } else {
    const double s = 2 * std::sqrt(1 + r22 - r00 - r11);
    q = {(r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, s / 4};
  }
  return q;
}

}  // namespace

std::string exavatar_pose_json(const body::SmplxPose& pose) {
  const nlohmann::json j{{"root_pose", numbers(pose.global_orient, false)},
                         {"body_pose", numbers(pose.body_pose, true)},
                         {"jaw_pose", numbers(pose.jaw_pose, false)},
                         {"leye_pose", numbers(pose.leye_pose, false)},
                         {"reye_pose", numbers(pose.reye_pose, false)},
                         {"lhand_pose", numbers(pose.left_hand_pose, true)},
                         {"rhand_pose", numbers(pose.right_hand_pose, true)},
                         {"expr", numbers(pose.expression, false)},
                         {"trans", numbers(pose.transl, false)}};
  return j.dump() + "\n";
}

body::SmplxPose pose_in_camera(const body::SmplxPose& world, const std::array<double, 16>& world_to_camera,
                               const at::Tensor& rest_pelvis) {
  const at::Tensor r = rotation_of(world_to_camera);
  const at::Tensor t =
      at::tensor(std::vector<double>{world_to_camera[3], world_to_camera[7], world_to_camera[11]}, at::kDouble);
  const at::Tensor pelvis = rest_pelvis.to(at::kCPU, at::kDouble);
  body::SmplxPose camera = world;
  const at::Tensor root = body::axis_angle_to_matrix(world.global_orient.to(at::kDouble));
  camera.global_orient = body::matrix_to_axis_angle(r.matmul(root)).to(world.global_orient.scalar_type());
  camera.transl = (r.matmul(pelvis + world.transl.to(at::kDouble)) + t - pelvis).to(world.transl.scalar_type());
  return camera;
}

void write_smplx_parameter_folder(const std::string& folder, const at::Tensor& betas,
                                  const std::map<int64_t, body::SmplxPose>& poses,
                                  const std::map<std::string, std::string>& extra_files, bool overwrite) {
  fs::create_directories(fs::path(folder).parent_path().empty() ? fs::path(".") : fs::path(folder).parent_path());
  AtomicFolder out(folder);
  out.add("shape_param.json", bytes_of(numbers(betas, false).dump() + "\n"));
  for (const auto& [frame, pose] : poses)
    out.add("smplx_params/" + std::to_string(frame) + ".json", bytes_of(exavatar_pose_json(pose)));
  for (const auto& [path, text] : extra_files) out.add(path, bytes_of(text));
  out.commit(overwrite);
}

void write_colmap_model(const std::string& folder, const std::vector<ColmapFrame>& frames, bool overwrite) {
  std::vector<std::tuple<double, double, double, double, int64_t, int64_t>> intrinsics;
  std::string cameras =
      "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
  std::string images =
      "# Image list with two lines of data per image:\n"
      "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n";
  char line[512];
  for (size_t i = 0; i < frames.size(); ++i) {
    const Camera& c = frames[i].camera;
    const auto key = std::make_tuple(c.fx, c.fy, c.cx, c.cy, c.width, c.height);
    auto found = std::find(intrinsics.begin(), intrinsics.end(), key);
    if (found == intrinsics.end()) {
      intrinsics.push_back(key);
      found = intrinsics.end() - 1;
      std::snprintf(line, sizeof(line), "%zu PINHOLE %lld %lld %.10g %.10g %.10g %.10g\n", intrinsics.size(),
                    (long long)c.width, (long long)c.height, c.fx, c.fy, c.cx, c.cy);
      cameras += line;
    }
    const auto q = quaternion_of(c.world_to_camera);
    const auto& m = c.world_to_camera;
    std::snprintf(line, sizeof(line), "%zu %.12g %.12g %.12g %.12g %.12g %.12g %.12g %td %s\n\n", i + 1, q[0], q[1],
                  q[2], q[3], m[3], m[7], m[11], found - intrinsics.begin() + 1, frames[i].image_name.c_str());
    images += line;
  }
  fs::create_directories(fs::path(folder) / "sparse");
  write_file_atomically((fs::path(folder) / "sparse" / "cameras.txt").string(), bytes_of(cameras), overwrite);
  write_file_atomically((fs::path(folder) / "sparse" / "images.txt").string(), bytes_of(images), overwrite);
}

void write_split_file(const std::string& path, const std::vector<std::string>& image_names, bool overwrite) {
  std::string text;
  for (const std::string& name : image_names) text += name + "\n";
  write_file_atomically(path, bytes_of(text), overwrite);
}

}  // namespace sfgs::data
