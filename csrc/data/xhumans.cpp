#include "data/xhumans.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "data/json_values.h"
#include "io/npz.h"

namespace sfgs::data {
namespace fs = std::filesystem;

namespace {

// X-Humans renders at 30 fps; times only matter relative to each other.
constexpr double kXhumansFramesPerSecond = 30.0;
constexpr const char* kConverter = "python3 python/tools/convert_xhumans_smplx.py";

std::vector<fs::path> sorted_entries(const fs::path& folder, const std::string& prefix, const std::string& suffix) {
  std::vector<fs::path> out;
  if (!fs::is_directory(folder)) return out;
  for (const auto& e : fs::directory_iterator(folder)) {
    const std::string name = e.path().filename().string();
    if (name.size() > prefix.size() + suffix.size() && name.rfind(prefix, 0) == 0 &&
        name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0)
      out.push_back(e.path());
  }
  std::sort(out.begin(), out.end());
  return out;
}

int64_t number_between(const std::string& name, const std::string& prefix, const std::string& suffix) {
  const std::string digits = name.substr(prefix.size(), name.size() - prefix.size() - suffix.size());
  TORCH_CHECK(!digits.empty() && digits.find_first_not_of("0123456789") == std::string::npos, "X-Humans file '", name,
              "' does not follow ", prefix, "<number>", suffix);
  return std::stoll(digits);
}

std::string numbered_file_name(const char* pattern, int64_t number) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), pattern, static_cast<long long>(number));
  return buffer;
}

SmplxPose read_xhumans_pose(const fs::path& take, int64_t number) {
  const fs::path json_path = take / "SMPLX" / numbered_file_name("mesh-f%05lld_smplx.json", number);
  if (!fs::exists(json_path)) {
    const fs::path pkl = take / "SMPLX" / numbered_file_name("mesh-f%05lld_smplx.pkl", number);
    TORCH_CHECK(!fs::exists(pkl), "X-Humans SMPL-X parameters '", pkl.string(),
                "' are pickles; convert them once with `", kConverter, " ", take.parent_path().parent_path().string(),
                "`");
    TORCH_CHECK(false, "X-Humans take '", take.string(), "' has no SMPL-X parameters for frame ", number,
                " (expected '", json_path.string(), "')");
  }
  const nlohmann::json j = read_json_file(json_path.string());
  const std::string where = json_path.string();
  const auto field = [&](const char* key, std::vector<int64_t> shape) {
    TORCH_CHECK(j.contains(key), "'", where, "' lacks the SMPL-X parameter '", key, "'");
    return json_numbers(j.at(key), shape, where + ": " + key);
  };
  SmplxPose p;
  p.global_orient = field("global_orient", {3});
  p.body_pose = field("body_pose", {21, 3});
  p.jaw_pose = field("jaw_pose", {3});
  p.leye_pose = field("leye_pose", {3});
  p.reye_pose = field("reye_pose", {3});
  p.left_hand_pose = field("left_hand_pose", {15, 3});
  p.right_hand_pose = field("right_hand_pose", {15, 3});
  p.expression = j.contains("expression") ? field("expression", {-1}) : at::zeros({0});
  p.transl = field("transl", {3});
  // DECA's 50 expression coefficients replace the 10 of the fit when ExAvatar's face fitting is present.
  const fs::path flame = take / "render" / "flame_init" / "flame_params" / numbered_file_name("%06lld.json", number);
  if (fs::exists(flame)) {
    const nlohmann::json f = read_json_file(flame.string());
    const bool valid = f.value("is_valid", true);
    const at::Tensor expr = json_numbers(f.at("expr"), {-1}, flame.string() + ": expr");
    p.expression = valid ? expr : at::zeros_like(expr);
  }
  return p;
}

}  // namespace

Dataset read_xhumans(const std::string& subject_folder) {
  const fs::path root(subject_folder);
  Dataset d;
  d.source = subject_folder;
  d.format = "xhumans";
  at::Tensor fallback_betas;
  for (const auto& [split_name, split] :
       std::vector<std::pair<std::string, Split>>{{"train", Split::kTrain}, {"test", Split::kTest}}) {
    for (const fs::path& take : sorted_entries(root / split_name, "Take", "")) {
      const fs::path render = take / "render";
      const std::vector<fs::path> images = sorted_entries(render / "image", "color_", ".png");
      TORCH_CHECK(!images.empty(), "X-Humans take '", take.string(), "' has no render/image/color_*.png");
      const std::string cameras_path = (render / "cameras.npz").string();
      const io::NpzArchive cameras(cameras_path);
      const at::Tensor intrinsic = cameras.read("intrinsic").to(at::kDouble);
      const at::Tensor extrinsic = cameras.read("extrinsic").to(at::kDouble);
      TORCH_CHECK(intrinsic.sizes() == at::IntArrayRef({3, 3}), "'", cameras_path, "': intrinsic must be 3 x 3, got ",
                  intrinsic.sizes());
      TORCH_CHECK(extrinsic.dim() == 3 && extrinsic.size(0) == int64_t(images.size()) && extrinsic.size(1) >= 3 &&
                      extrinsic.size(2) == 4,
                  "'", cameras_path, "': extrinsic must be (", images.size(), ", 3 or 4, 4), one per image, got ",
                  extrinsic.sizes());
      const auto [width, height] = image_size(images.front().string());
      const int64_t sequence = int64_t(d.sequences.size());
      d.sequences.push_back(split_name + "/" + take.filename().string());
      for (size_t i = 0; i < images.size(); ++i) {
        const std::string name = images[i].filename().string();
        const int64_t number = number_between(name, "color_", ".png");
        FrameRecord r;
        r.name = d.sequences.back() + "/" + images[i].stem().string();
        r.time = double(number) / kXhumansFramesPerSecond;
        r.sequence = sequence;
        r.camera.fx = intrinsic[0][0].item<double>();
        r.camera.fy = intrinsic[1][1].item<double>();
        r.camera.cx = intrinsic[0][2].item<double>();
        r.camera.cy = intrinsic[1][2].item<double>();
        r.camera.width = width;
        r.camera.height = height;
        // Extrinsics are world-to-camera [R | t] (rows of the 4 x 4 matrix beyond the third are implied).
        const at::Tensor e = extrinsic[int64_t(i)];
        for (int row = 0; row < 3; ++row)
          for (int col = 0; col < 4; ++col)
            r.camera.world_to_camera[size_t(row * 4 + col)] = e[row][col].item<double>();
        r.camera.world_to_camera[12] = r.camera.world_to_camera[13] = r.camera.world_to_camera[14] = 0;
        r.camera.world_to_camera[15] = 1;
        r.image_path = images[i].string();
        r.mask_path = (render / "depth" / numbered_file_name("depth_%06lld.tiff", number)).string();
        r.mask_encoding = MaskEncoding::kDepthForeground;
        r.pose = read_xhumans_pose(take, number);
        if (!fallback_betas.defined()) {
          const nlohmann::json j =
              read_json_file((take / "SMPLX" / numbered_file_name("mesh-f%05lld_smplx.json", number)).string());
          if (j.contains("betas")) fallback_betas = json_numbers(j.at("betas"), {-1}, "betas");
        }
        d.splits[split].push_back(d.size());
        d.frames.push_back(std::move(r));
      }
    }
  }
  TORCH_CHECK(!d.frames.empty(), "'", subject_folder, "' holds no X-Humans takes (expected train/TakeN or test/TakeN)");
  // ExAvatar's fitted 100-d shape replaces X-Humans' 10 betas when present.
  const fs::path shape = root / "smplx_optimized" / "shape_param.json";
  if (fs::exists(shape)) {
    d.betas = json_numbers(read_json_file(shape.string()), {-1}, shape.string());
  } else {
    TORCH_CHECK(fallback_betas.defined(), "'", subject_folder,
                "': no smplx_optimized/shape_param.json and no betas in "
                "the SMPL-X files");
    d.betas = fallback_betas;
  }
  d.validate();
  return d;
}

}  // namespace sfgs::data
