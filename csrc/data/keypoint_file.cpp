#include "data/keypoint_file.h"

#include <ATen/ATen.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "body/wholebody_keypoints.h"
#include "common/atomic_file.h"

namespace sfgs::data {
namespace fs = std::filesystem;

namespace {

constexpr int64_t kValuesPerKeypoint = 3;  // x, y, score

std::string keypoint_label(int64_t index) {
  return std::to_string(index) + " (" + body::wholebody_keypoint_names()[size_t(index)] + ")";
}

double number_at(const nlohmann::json& value, const std::string& path, const std::string& what) {
  TORCH_CHECK(value.is_number(), "keypoint file '", path, "': ", what, " must be a number, got ", value.dump());
  const double v = value.get<double>();
  TORCH_CHECK(std::isfinite(v), "keypoint file '", path, "': ", what, " is not finite (", v, ")");
  return v;
}

}  // namespace

at::Tensor read_wholebody_keypoints(const std::string& path) {
  std::ifstream in(path);
  TORCH_CHECK(in.good(), "cannot open keypoint file '", path, "' (expected ", body::kWholeBodyKeypointCount,
              " [x, y, score] triples as JSON)");
  std::stringstream text;
  text << in.rdbuf();
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text.str());
  } catch (const nlohmann::json::exception& e) {
    const std::string s = text.str();
    const bool python_special = s.find("NaN") != std::string::npos || s.find("Infinity") != std::string::npos;
    TORCH_CHECK(
        false, "keypoint file '", path, "' is not valid JSON: ", e.what(),
        python_special ? " (it holds NaN or Infinity, which Python's json module writes but JSON has not)" : "");
  }
  TORCH_CHECK(j.is_array(), "keypoint file '", path, "': expected a list of ", body::kWholeBodyKeypointCount,
              " [x, y, score] triples, got ", j.type_name());
  const int64_t count = body::kWholeBodyKeypointCount;
  at::Tensor out = at::empty({count, kValuesPerKeypoint}, at::kFloat);
  auto a = out.accessor<float, 2>();
  const bool flat = !j.empty() && j.front().is_number();
  if (flat) {
    TORCH_CHECK(int64_t(j.size()) == count * kValuesPerKeypoint, "keypoint file '", path, "': expected ", count,
                " keypoints (", count * kValuesPerKeypoint, " numbers in a flat list), got ", j.size(), " numbers");
    for (int64_t i = 0; i < count; ++i)
      for (int64_t k = 0; k < kValuesPerKeypoint; ++k)
        a[i][k] = float(number_at(j[size_t(kValuesPerKeypoint * i + k)], path, "keypoint " + keypoint_label(i)));
    return out;
  }
  TORCH_CHECK(int64_t(j.size()) == count, "keypoint file '", path, "': expected ", count,
              " keypoints (COCO-WholeBody: 17 body, 6 feet, 68 face, 2 x 21 hands), got ", j.size());
  for (int64_t i = 0; i < count; ++i) {
    const nlohmann::json& triple = j[size_t(i)];
    TORCH_CHECK(triple.is_array() && int64_t(triple.size()) == kValuesPerKeypoint, "keypoint file '", path,
                "': keypoint ", keypoint_label(i), " must be [x, y, score], got ", triple.dump());
    for (int64_t k = 0; k < kValuesPerKeypoint; ++k)
      a[i][k] = float(number_at(triple[size_t(k)], path, "keypoint " + keypoint_label(i)));
  }
  return out;
}

void write_wholebody_keypoints(const std::string& path, const at::Tensor& keypoints, bool overwrite) {
  TORCH_CHECK(keypoints.dim() == 2 && keypoints.size(0) == body::kWholeBodyKeypointCount &&
                  keypoints.size(1) == kValuesPerKeypoint,
              "write_wholebody_keypoints: expected (", body::kWholeBodyKeypointCount, ", 3) keypoints, got ",
              keypoints.sizes());
  const at::Tensor k = keypoints.detach().to(at::kCPU, at::kDouble).contiguous();
  TORCH_CHECK(k.isfinite().all().item<bool>(), "write_wholebody_keypoints: '", path, "': keypoints must be finite");
  auto a = k.accessor<double, 2>();
  std::string text = "[";
  char entry[96];
  for (int64_t i = 0; i < k.size(0); ++i) {
    std::snprintf(entry, sizeof(entry), "%s[%.2f, %.2f, %.3f]", i ? ", " : "", a[i][0], a[i][1], a[i][2]);
    text += entry;
  }
  text += "]\n";
  write_file_atomically(path, std::vector<unsigned char>(text.begin(), text.end()), overwrite);
}

std::map<int64_t, std::string> list_keypoint_files(const std::string& folder) {
  const fs::path dir = fs::path(folder) / kKeypointFolder;
  TORCH_CHECK(fs::is_directory(dir), "'", folder, "' has no ", kKeypointFolder,
              "/ folder (per-frame <frame>.json "
              "files of ",
              body::kWholeBodyKeypointCount, " [x, y, score] whole-body keypoints, as DWPose writes them)");
  std::map<int64_t, std::string> files;
  for (const fs::directory_entry& e : fs::directory_iterator(dir)) {
    if (e.path().extension() != ".json") continue;
    const std::string stem = e.path().stem().string();
    TORCH_CHECK(!stem.empty() && stem.find_first_not_of("0123456789") == std::string::npos, "keypoint file '",
                e.path().string(), "': the name must be a frame number like 12.json");
    files[std::stoll(stem)] = e.path().string();
  }
  TORCH_CHECK(!files.empty(), "'", dir.string(), "' holds no keypoint file like 0.json");
  return files;
}

}  // namespace sfgs::data
