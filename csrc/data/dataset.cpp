#include "data/dataset.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <cstdio>
#include <filesystem>
#include <map>
#include <sstream>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "common/checksum.h"
#include "data/constants.h"
#include "data/json_values.h"
#include "data/neuman.h"
#include "data/xhumans.h"

namespace sfgs::data {
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

constexpr const char* kFormatName = "sfgs-dataset";
constexpr int kFormatVersion = 1;
constexpr const char* kIndexFile = "dataset.json";

// The shape each pose field has in a dataset (-1: any length).
std::vector<int64_t> stored_shape(const SmplxPose::Field& f) {
  if (f.joints == 0) return {-1};
  if (f.joints == 1) return {3};
  return {f.joints, 3};
}

json tensor_to_json(const at::Tensor& t) {
  const at::Tensor flat = t.detach().cpu().to(at::kDouble).contiguous().view({-1});
  return json(std::vector<double>(flat.data_ptr<double>(), flat.data_ptr<double>() + flat.numel()));
}

json pose_to_json(const SmplxPose& pose, bool in_camera_frame) {
  json j;
  for (const SmplxPose::Field& f : SmplxPose::fields()) j[f.name] = tensor_to_json(pose.*(f.member));
  j["in_camera_frame"] = in_camera_frame;
  return j;
}

SmplxPose pose_from_json(const json& j, const std::string& where) {
  SmplxPose pose;
  TORCH_CHECK(j.is_object(), where, ": expected an object of SMPL-X parameters");
  for (const SmplxPose::Field& f : SmplxPose::fields()) {
    TORCH_CHECK(j.contains(f.name), where, ": missing SMPL-X parameter '", f.name, "'");
    pose.*(f.member) = json_numbers(j.at(f.name), stored_shape(f), where + "." + f.name);
  }
  return pose;
}

json camera_to_json(const Camera& c) {
  return json{{"fx", c.fx},
              {"fy", c.fy},
              {"cx", c.cx},
              {"cy", c.cy},
              {"width", c.width},
              {"height", c.height},
              {"world_to_camera", std::vector<double>(c.world_to_camera.begin(), c.world_to_camera.end())}};
}

Camera camera_from_json(const json& j, const std::string& where) {
  TORCH_CHECK(j.is_object(), where, ": expected a camera object");
  for (const char* key : {"fx", "fy", "cx", "cy", "width", "height", "world_to_camera"})
    TORCH_CHECK(j.contains(key), where, ": missing camera field '", key, "'");
  Camera c;
  c.fx = j.at("fx").get<double>();
  c.fy = j.at("fy").get<double>();
  c.cx = j.at("cx").get<double>();
  c.cy = j.at("cy").get<double>();
  c.width = j.at("width").get<int64_t>();
  c.height = j.at("height").get<int64_t>();
  const auto m = j.at("world_to_camera").get<std::vector<double>>();
  TORCH_CHECK(m.size() == 16, where, ".world_to_camera: expected 16 numbers (row-major 4x4), got ", m.size());
  std::copy(m.begin(), m.end(), c.world_to_camera.begin());
  return c;
}

const std::map<Split, const char*>& split_names() {
  static const std::map<Split, const char*> names = {
      {Split::kTrain, "train"}, {Split::kVal, "val"}, {Split::kTest, "test"}};
  return names;
}

// A path of the index, relative to the dataset folder and inside it: absolute paths and '..' are refused (a
// symlink the user placed inside the folder is followed as usual).
std::string resolve(const std::string& folder, const std::string& relative, const std::string& what) {
  if (relative.empty()) return relative;
  const fs::path path(relative);
  bool leaves = path.has_root_name() || path.has_root_directory();
  for (const fs::path& part : path) leaves = leaves || part == "..";
  TORCH_CHECK(!leaves, what, " '", relative, "' leaves the dataset folder: the paths of ", kIndexFile,
              " are relative to it, without '..'");
  return (fs::path(folder) / path).string();
}

std::string relative_to(const std::string& folder, const std::string& path) {
  return path.empty() ? path : fs::relative(fs::path(path), fs::path(folder)).generic_string();
}

}  // namespace

const char* split_name(Split split) { return split_names().at(split); }

Split interleaved_split(int64_t frame) {
  if (frame % kInterleavedSplitPeriod == kInterleavedValidationOffset) return Split::kVal;
  if (frame % kInterleavedSplitPeriod == kInterleavedTestOffset) return Split::kTest;
  return Split::kTrain;
}

const std::vector<int64_t>& Dataset::split(Split s) const {
  static const std::vector<int64_t> empty;
  const auto it = splits.find(s);
  return it == splits.end() ? empty : it->second;
}

int64_t Dataset::frames_with_keypoints(Split s) const {
  const std::vector<int64_t>& indices = split(s);
  return std::count_if(indices.begin(), indices.end(),
                       [&](int64_t f) { return !frames[size_t(f)].keypoints_path.empty(); });
}

Frame Dataset::load(int64_t index) const {
  TORCH_CHECK(index >= 0 && index < size(), "Dataset::load: frame ", index, " out of range [0, ", size(), ")");
  const FrameRecord& r = frames[size_t(index)];
  Frame f;
  f.image = read_image_rgb(r.image_path);
  const int64_t h = f.image.size(0), w = f.image.size(1);
  TORCH_CHECK(h == r.camera.height && w == r.camera.width, "image '", r.image_path, "' is ", w, " x ", h,
              " but its camera says ", r.camera.width, " x ", r.camera.height);
  f.mask = r.mask_path.empty() ? at::ones({h, w}) : read_mask(r.mask_path, r.mask_encoding);
  TORCH_CHECK(f.mask.size(0) == h && f.mask.size(1) == w, "mask '", r.mask_path, "' is ", f.mask.size(1), " x ",
              f.mask.size(0), " but its image is ", w, " x ", h);
  f.eval_mask = r.eval_mask_path.empty() ? f.mask : read_mask(r.eval_mask_path, r.eval_mask_encoding);
  TORCH_CHECK(f.eval_mask.size(0) == h && f.eval_mask.size(1) == w, "evaluation mask '", r.eval_mask_path,
              "' does not match its image size ", w, " x ", h);
  return f;
}

std::optional<double> Dataset::replay_time(int64_t index) const {
  TORCH_CHECK(index >= 0 && index < size(), "Dataset::replay_time: frame ", index, " out of range [0, ", size(), ")");
  return ReplayClock(*this).time_of(frames[size_t(index)]);
}

ReplayClock::ReplayClock(const Dataset& dataset) {
  std::vector<int64_t> training = dataset.split(Split::kTrain);
  if (training.empty()) {
    training.resize(dataset.frames.size());
    std::iota(training.begin(), training.end(), int64_t(0));
  }
  std::map<int64_t, std::vector<double>> sequence_times;
  for (int64_t t : training) {
    const FrameRecord& r = dataset.frames[size_t(t)];
    sequence_times[r.sequence].push_back(r.time);
  }
  lo_ = INFINITY;
  hi_ = -INFINITY;
  for (auto& [sequence, times] : sequence_times) {
    std::sort(times.begin(), times.end());
    // A held-out frame inside the span lies at most half the largest gap from a trained time; a frame just past
    // either end (the interleaved split's last test frame) is granted the same reach, with the end's time.
    double largest_gap = 0;
    for (size_t i = 1; i < times.size(); ++i) largest_gap = std::max(largest_gap, times[i] - times[i - 1]);
    spans_[sequence] = {times.front(), times.back(), largest_gap / 2 * (1 + kReplayReachSlack)};
    lo_ = std::min(lo_, times.front());
    hi_ = std::max(hi_, times.back());
  }
}

std::optional<double> ReplayClock::time_of(const FrameRecord& frame) const {
  const auto span = spans_.find(frame.sequence);
  if (span == spans_.end()) return std::nullopt;
  const Span& s = span->second;
  if (!(frame.time >= s.first - s.reach && frame.time <= s.last + s.reach)) return std::nullopt;
  if (hi_ - lo_ <= 0) return 0.0;
  return std::clamp(2.0 * (frame.time - lo_) / (hi_ - lo_) - 1.0, -1.0, 1.0);
}

void Dataset::validate() const {
  TORCH_CHECK(!frames.empty(), "dataset '", source, "' has no frames");
  TORCH_CHECK(!sequences.empty(), "dataset '", source, "' has no sequence names");
  TORCH_CHECK(betas.defined() && betas.dim() == 1, "dataset '", source, "': betas must be a 1-D tensor");
  for (const auto& [s, indices] : splits)
    for (int64_t i : indices)
      TORCH_CHECK(i >= 0 && i < size(), "dataset '", source, "': split '", split_names().at(s), "' names frame ", i,
                  " of ", size());
  TORCH_CHECK(!true_betas.defined() || true_betas.dim() == 1, "dataset '", source,
              "': true betas must be a 1-D tensor");
  const auto check_pose = [&](const FrameRecord& r, const SmplxPose& pose, const char* which) {
    for (const SmplxPose::Field& f : SmplxPose::fields()) {
      const at::Tensor& t = pose.*(f.member);
      TORCH_CHECK(t.defined(), "dataset '", source, "': frame '", r.name, "' lacks ", which, " parameter ", f.name);
      const std::vector<int64_t> shape = stored_shape(f);
      if (shape[0] != -1)
        TORCH_CHECK(t.sizes() == at::IntArrayRef(shape), "dataset '", source, "': frame '", r.name, "' ", which, " ",
                    f.name, " has shape ", t.sizes());
    }
    const std::string non_finite = pose.non_finite();
    TORCH_CHECK(non_finite.empty(), "dataset '", source, "': frame '", r.name, "' ", which, " parameter ", non_finite);
  };
  // A frame is named within its sequence: two of one name there could not be told apart (their renders and
  // per-frame scores would overwrite each other).
  std::map<std::pair<int64_t, std::string>, size_t> named;
  for (size_t i = 0; i < frames.size(); ++i) {
    const auto [it, added] = named.emplace(std::make_pair(frames[i].sequence, frames[i].name), i);
    TORCH_CHECK(added, "dataset '", source, "': frames ", it->second, " and ", i, " share the name '", frames[i].name,
                "'", sequences.size() > 1 ? " in one sequence" : "", ": give every frame a name of its own");
  }
  for (const FrameRecord& r : frames) {
    TORCH_CHECK(r.sequence >= 0 && r.sequence < int64_t(sequences.size()), "dataset '", source, "': frame '", r.name,
                "' names sequence ", r.sequence);
    const std::string camera = camera_problem(r.camera);
    TORCH_CHECK(camera.empty(), "dataset '", source, "': frame '", r.name, "' camera: ", camera);
    check_pose(r, r.pose, "SMPL-X");
    if (r.true_pose) check_pose(r, *r.true_pose, "true SMPL-X");
  }
}

std::string Dataset::fingerprint() const {
  uint32_t crc = crc32_of(format.data(), format.size());
  const auto add_double = [&](double v) { crc = crc32_of(&v, sizeof(v), crc); };
  for (const FrameRecord& r : frames) {
    crc = crc32_of(r.name.data(), r.name.size(), crc);
    add_double(r.time);
    add_double(double(r.sequence));
    for (double v : r.camera.world_to_camera) add_double(v);
    for (double v :
         {r.camera.fx, r.camera.fy, r.camera.cx, r.camera.cy, double(r.camera.width), double(r.camera.height)})
      add_double(v);
    for (const SmplxPose::Field& f : SmplxPose::fields()) crc = crc32_of((r.pose.*(f.member)).to(at::kFloat), crc);
    add_double(r.pose_in_camera_frame ? 1 : 0);
  }
  for (const auto& [split, name] : split_names()) {
    add_double(-1.0 - double(int(split)));  // marks where each split's indices begin
    for (int64_t i : this->split(split)) add_double(double(i));
  }
  crc = crc32_of(betas.to(at::kFloat), crc);
  char hex[16];
  std::snprintf(hex, sizeof(hex), "%08x", crc);
  return std::string(hex) + "-" + std::to_string(frames.size());
}

Dataset read_sfgs_dataset(const std::string& folder) {
  const std::string index = (fs::path(folder) / kIndexFile).string();
  TORCH_CHECK(fs::exists(index), "cannot open '", index, "' (an sfgs dataset folder holds dataset.json)");
  const json j = read_json_file(index);
  TORCH_CHECK(j.value("format", "") == kFormatName, "'", index, "': expected format '", kFormatName, "', got '",
              j.value("format", ""), "'");
  TORCH_CHECK(j.value("version", 0) == kFormatVersion, "'", index, "': unsupported version ", j.value("version", 0),
              " (this sfgs reads version ", kFormatVersion, ")");
  Dataset d;
  d.source = folder;
  d.format = "sfgs";
  try {
    d.betas = json_numbers(j.at("betas"), {-1}, index + ": betas");
    if (j.contains("betas_truth")) d.true_betas = json_numbers(j.at("betas_truth"), {-1}, index + ": betas_truth");
    d.sequences = j.value("sequences", std::vector<std::string>{"sequence"});
    const json& frames = j.at("frames");
    TORCH_CHECK(frames.is_array(), index, ": 'frames' must be an array");
    for (size_t i = 0; i < frames.size(); ++i) {
      const json& f = frames[i];
      const std::string where = index + ": frames[" + std::to_string(i) + "]";
      FrameRecord r;
      r.name = f.at("name").get<std::string>();
      r.time = f.at("time").get<double>();
      r.sequence = f.value("sequence", int64_t(0));
      r.camera = camera_from_json(f.at("camera"), where + ".camera");
      r.pose = pose_from_json(f.at("smplx"), where + ".smplx");
      r.pose_in_camera_frame = f.at("smplx").value("in_camera_frame", false);
      if (f.contains("smplx_truth")) r.true_pose = pose_from_json(f.at("smplx_truth"), where + ".smplx_truth");
      r.image_path = resolve(folder, f.at("image").get<std::string>(), where + ".image");
      r.mask_path = resolve(folder, f.value("mask", ""), where + ".mask");
      r.mesh_path = resolve(folder, f.value("mesh", ""), where + ".mesh");
      r.keypoints_path = resolve(folder, f.value("keypoints", ""), where + ".keypoints");
      d.frames.push_back(std::move(r));
    }
    for (const auto& [split, name] : split_names())
      if (j.contains("splits") && j.at("splits").contains(name))
        d.splits[split] = j.at("splits").at(name).get<std::vector<int64_t>>();
  } catch (const json::exception& e) {
    TORCH_CHECK(false, "'", index, "' does not follow the sfgs dataset format: ", e.what());
  }
  d.validate();
  return d;
}

void write_sfgs_dataset(const Dataset& d, const std::string& folder, bool overwrite) {
  d.validate();
  json frames = json::array();
  for (const FrameRecord& r : d.frames) {
    TORCH_CHECK(r.eval_mask_path.empty() || r.eval_mask_path == r.mask_path, "write_sfgs_dataset: frame '", r.name,
                "' has a separate evaluation mask, which the format cannot hold");
    json f{{"name", r.name},
           {"time", r.time},
           {"sequence", r.sequence},
           {"camera", camera_to_json(r.camera)},
           {"smplx", pose_to_json(r.pose, r.pose_in_camera_frame)},
           {"image", relative_to(folder, r.image_path)}};
    if (!r.mask_path.empty()) f["mask"] = relative_to(folder, r.mask_path);
    if (!r.mesh_path.empty()) f["mesh"] = relative_to(folder, r.mesh_path);
    if (!r.keypoints_path.empty()) f["keypoints"] = relative_to(folder, r.keypoints_path);
    if (r.true_pose) f["smplx_truth"] = pose_to_json(*r.true_pose, r.pose_in_camera_frame);
    frames.push_back(std::move(f));
  }
  json splits = json::object();
  for (const auto& [split, name] : split_names()) splits[name] = d.split(split);
  json j{{"format", kFormatName},    {"version", kFormatVersion},
         {"sequences", d.sequences}, {"betas", tensor_to_json(d.betas)},
         {"frames", frames},         {"splits", splits}};
  if (d.true_betas.defined()) j["betas_truth"] = tensor_to_json(d.true_betas);
  const std::string text = j.dump(1);
  write_file_atomically((fs::path(folder) / kIndexFile).string(), std::vector<unsigned char>(text.begin(), text.end()),
                        overwrite);
}

Dataset read_dataset(const std::string& folder) {
  TORCH_CHECK(fs::is_directory(folder), "dataset folder '", folder, "' does not exist");
  if (fs::exists(fs::path(folder) / kIndexFile)) return read_sfgs_dataset(folder);
  if (fs::exists(fs::path(folder) / "sparse" / "cameras.txt")) return read_neuman(folder);
  if (fs::is_directory(fs::path(folder) / "train") || fs::is_directory(fs::path(folder) / "test"))
    return read_xhumans(folder);
  TORCH_CHECK(false, "'", folder,
              "' is not a dataset folder: expected dataset.json (sfgs), sparse/cameras.txt "
              "(NeuMan) or train/ and test/ takes (X-Humans)");
}

}  // namespace sfgs::data
