#include "train/web_export.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "body/skeleton.h"
#include "common/atomic_file.h"
#include "body/constants.h"
#include "ops/splat/constants.h"
#include "train/constants.h"
#include "train/web_assets.h"

namespace sfgs::train {
namespace fs = std::filesystem;

namespace {

constexpr const char* kManifestFile = "data/manifest.js";
constexpr const char* kDataScriptsMarker = "<!-- sfgs:data -->";
constexpr int64_t kWeightTotal = 255;     // 8-bit weights of a Gaussian sum to exactly this
constexpr int64_t kOffsetLevels = 127;    // int8 mean offsets: steps of (largest offset of the frame) / this
constexpr int64_t kLogScaleLevels = 127;  // int8 log-scale offsets, likewise
constexpr int64_t kColourLevels = 255;    // uint8 albedo and opacity

// Every joint at rest: the avatar adds the model's mean hand to given hand poses unless its hands are absolute, so
// the rest hands are given as minus that mean. The skinning transforms of this pose are the identity.
body::SmplxPose rest_pose(model::Avatar& avatar) {
  body::SmplxPose pose = body::SmplxPose::zeros(0);
  if (!avatar->config().flat_hand_mean) {
    pose.left_hand_pose = -avatar->hand_mean(body::Side::kLeft).cpu();
    pose.right_hand_pose = -avatar->hand_mean(body::Side::kRight).cpu();
  }
  return pose;
}

// The viewer's influences: each Gaussian's strongest kWebViewerInfluences joints, their weights renormalised and
// stored as integers that sum to kWeightTotal exactly (the largest remainders round up), so the viewer needs no
// renormalisation of its own.
struct ViewerInfluences {
  at::Tensor joints;   // (N, K) uint8
  at::Tensor weights;  // (N, K) uint8, each row summing to kWeightTotal
};

ViewerInfluences viewer_influences(const skin::SkinningWeights& skinning) {
  TORCH_CHECK(skinning.joint_count <= 256, "the web viewer stores joints as bytes; this body has ",
              skinning.joint_count, " joints");
  const skin::SkinningWeights w = skinning.to(at::kCPU, at::kDouble);
  const int64_t k = std::min<int64_t>(kWebViewerInfluences, w.weights.size(1));
  const auto [strongest, column] = w.weights.topk(k, 1);
  const at::Tensor normalised = strongest / strongest.sum(1, true);
  const at::Tensor scaled = normalised * double(kWeightTotal);
  at::Tensor units = scaled.floor();
  const at::Tensor missing = (double(kWeightTotal) - units.sum(1, true)).round();
  const at::Tensor rank = at::argsort(at::argsort(units - scaled, 1, false), 1, false);  // 0: largest remainder
  units = units + (rank < missing).to(at::kDouble);
  return {w.joints.gather(1, column).to(at::kByte), units.to(at::kByte)};
}

// [A | t] = sum_k w_k T_{j_k} of every Gaussian, (N, 3, 4) float64, from the frame's transforms (J, 12) as the
// viewer reads them (float32): the arithmetic of web/pose_player.js.
at::Tensor blended_transforms(const ViewerInfluences& influences, const at::Tensor& transforms) {
  const int64_t n = influences.joints.size(0), k = influences.joints.size(1);
  const at::Tensor rows = transforms.to(at::kDouble).index_select(0, influences.joints.flatten().to(at::kLong));
  const at::Tensor weights = influences.weights.to(at::kDouble).div(double(kWeightTotal));
  return (rows.view({n, k, 12}) * weights.unsqueeze(2)).sum(1).view({n, 3, 4});
}

// Values as integers of `levels` steps either side of zero, the step fitting the largest magnitude.
struct Quantised {
  at::Tensor values;  // of the type asked for
  double step = 0;    // value = integer * step
};

Quantised quantise(const at::Tensor& values, int64_t levels, at::ScalarType type) {
  const double largest = values.abs().max().item<double>();
  Quantised q;
  q.step = largest > 0 ? largest / double(levels) : 0.0;
  q.values = (q.step > 0 ? (values / q.step).round().clamp(-levels, levels) : at::zeros_like(values)).to(type);
  return q;
}

const char* type_name(at::ScalarType type) {
  switch (type) {
    case at::kFloat:
      return "float32";
    case at::kInt:
      return "uint32";  // vertex indices, never negative
    case at::kChar:
      return "int8";
    case at::kByte:
      return "uint8";
    default:
      TORCH_CHECK(false, "no web viewer type for ", type);
  }
}

std::string base64(const std::vector<unsigned char>& bytes) {
  static const char* alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string text;
  text.reserve((bytes.size() + 2) / 3 * 4);
  for (size_t i = 0; i < bytes.size(); i += 3) {
    const uint32_t b0 = bytes[i], b1 = i + 1 < bytes.size() ? bytes[i + 1] : 0,
                   b2 = i + 2 < bytes.size() ? bytes[i + 2] : 0;
    const uint32_t triple = (b0 << 16) | (b1 << 8) | b2;
    text += alphabet[(triple >> 18) & 63];
    text += alphabet[(triple >> 12) & 63];
    text += i + 1 < bytes.size() ? alphabet[(triple >> 6) & 63] : '=';
    text += i + 2 < bytes.size() ? alphabet[triple & 63] : '=';
  }
  return text;
}

std::vector<unsigned char> text_bytes(const std::string& text) { return {text.begin(), text.end()}; }

// "out/web/" names the folder "out/web".
fs::path without_trailing_separators(const std::string& folder) {
  std::string path = folder;
  while (path.size() > 1 && path.back() == '/') path.pop_back();
  return path;
}

// The data scripts: buffers packed into files of at most kWebDataFileBytes (a file holds at least one frame), each
// written as `sfgsData[k] = "<base64>";`. Buffers start at multiples of 4 bytes, so the viewer views them in place.
class DataScripts {
 public:
  explicit DataScripts(AtomicFolder& folder) : folder_(folder) {}

  // Adds a CPU tensor to the file being filled; returns its manifest entry.
  nlohmann::json add(const at::Tensor& tensor) {
    const at::Tensor t = tensor.contiguous();
    const auto size = static_cast<size_t>(t.numel() * t.element_size());
    bytes_.resize((bytes_.size() + 3) / 4 * 4);
    const nlohmann::json entry = {{"file", files_.size()},
                                  {"offset", bytes_.size()},
                                  {"type", type_name(t.scalar_type())},
                                  {"length", t.numel()}};
    const auto* data = static_cast<const unsigned char*>(t.data_ptr());
    bytes_.insert(bytes_.end(), data, data + size);
    return entry;
  }
  // Closes the file being filled (named `name`, under data/) when it holds something.
  void close(const std::string& name) {
    if (bytes_.empty()) return;
    const std::string path = "data/" + name + ".js";
    const std::string script = "sfgsData[" + std::to_string(files_.size()) + "] = \"" + base64(bytes_) + "\";\n";
    folder_.add(path, text_bytes(script));
    written_ += int64_t(script.size());
    files_.push_back(path);
    bytes_.clear();
  }
  size_t pending_bytes() const { return bytes_.size(); }
  const std::vector<std::string>& files() const { return files_; }
  int64_t written_bytes() const { return written_; }

 private:
  AtomicFolder& folder_;
  std::vector<unsigned char> bytes_;
  std::vector<std::string> files_;
  int64_t written_ = 0;
};

}  // namespace

namespace {

constexpr const char* kManifestPrefix = "var sfgsExport = ";
constexpr size_t kForeignEntriesNamed = 5;  // an error names at most this many of a folder's foreign entries

// The files an earlier export wrote, from its manifest: the data files, the manifest and the viewer's files (listed
// since they were; before, this version's). Empty when the manifest is not one sfgs wrote.
std::set<std::string> files_of_export(const fs::path& folder) {
  std::ifstream in(folder / kManifestFile, std::ios::binary);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t end = text.find(";\nvar sfgsData");
  if (text.rfind(kManifestPrefix, 0) != 0 || end == std::string::npos) return {};
  const nlohmann::json manifest =
      nlohmann::json::parse(text.substr(std::strlen(kManifestPrefix), end - std::strlen(kManifestPrefix)), nullptr,
                            /*allow_exceptions=*/false);
  if (!manifest.is_object() || manifest.value("format", "") != "sfgs-web-viewer") return {};
  std::set<std::string> files{kManifestFile};
  const auto add = [&](const nlohmann::json& list) {
    if (!list.is_array()) return;
    for (const nlohmann::json& name : list)
      if (name.is_string()) files.insert(name.get<std::string>());
  };
  add(manifest.value("files", nlohmann::json()));
  if (manifest.contains("written"))
    add(manifest.at("written"));
  else
    for (const WebAsset& asset : web_assets()) files.insert(asset.name);
  return files;
}

}  // namespace

// An existing folder may be replaced only when it is empty or an earlier web export holding nothing but the files
// that export wrote: --force must never remove a run, a dataset or a file a user put beside the viewer.
void check_web_folder(const std::string& folder, bool overwrite) {
  const fs::path path = without_trailing_separators(folder);
  TORCH_CHECK(!path.empty() && path.filename() != "." && path.filename() != "..", "--web needs a folder name, got '",
              folder, "'");
  if (!fs::exists(path)) return;
  TORCH_CHECK(fs::is_directory(path), "'", folder, "' exists and is not a folder");
  if (fs::is_empty(path)) return;
  TORCH_CHECK(overwrite, "folder '", folder,
              "' exists and is not empty (pass --force to replace an earlier web export)");
  const std::set<std::string> own = fs::exists(path / "index.html") ? files_of_export(path) : std::set<std::string>();
  TORCH_CHECK(!own.empty(), "folder '", folder, "' is not an earlier web export (it lacks index.html and ",
              kManifestFile, " as sfgs writes them), so --force does not replace it; choose another folder");
  std::vector<std::string> foreign;
  for (auto it = fs::recursive_directory_iterator(path); it != fs::recursive_directory_iterator(); ++it) {
    const std::string name = fs::relative(it->path(), path).generic_string();
    if (it->is_directory() && !it->is_symlink() && name == "data") continue;
    if (it->is_directory() && !it->is_symlink()) {
      foreign.push_back(name + "/");
      it.disable_recursion_pending();
    } else if (own.count(name) == 0) {
      foreign.push_back(name);
    }
  }
  std::sort(foreign.begin(), foreign.end());
  std::string named;
  for (size_t k = 0; k < std::min(foreign.size(), kForeignEntriesNamed); ++k)
    named += (k ? ", '" : "'") + foreign[k] + "'";
  if (foreign.size() > kForeignEntriesNamed)
    named += " and " + std::to_string(foreign.size() - kForeignEntriesNamed) + " more";
  TORCH_CHECK(foreign.empty(), "folder '", folder, "' is an earlier web export but also holds ", named,
              ", which the export did not write; --force replaces only an export's own files: move them or choose "
              "another folder");
}

namespace {

nlohmann::json camera_json(const WebCamera& c) {
  const Camera& k = c.camera;
  return {{"width", k.width},
          {"height", k.height},
          {"fx", k.fx},
          {"fy", k.fy},
          {"cx", k.cx},
          {"cy", k.cy},
          {"world_to_camera", k.world_to_camera},
          {"near", k.near_plane},
          {"far", k.far_plane},
          {"target", c.target}};
}

// The thresholds of sfgs::render the viewer's shaders repeat (ops/splat/constants.h).
nlohmann::json splatting_json() {
  return {{"low_pass_variance", kLowPassVariancePx2},
          {"min_alpha", kMinAlpha},
          {"max_alpha", kMaxAlpha},
          {"fov_guard_fraction", kFovGuardFraction},
          {"psd_tolerance", kPsdTolerance},
          {"min_determinant", kMinDeterminant2D}};
}

// web/index.html with the data scripts loaded before the viewer's.
std::string index_html(const std::string& page, const std::vector<std::string>& data_files) {
  const size_t marker = page.find(kDataScriptsMarker);
  TORCH_CHECK(marker != std::string::npos, "web/index.html lacks the marker ", kDataScriptsMarker);
  std::string tags = "<script src=\"" + std::string(kManifestFile) + "\"></script>\n";
  for (const std::string& f : data_files) tags += "<script src=\"" + f + "\"></script>\n";
  return page.substr(0, marker) + tags + page.substr(marker + std::strlen(kDataScriptsMarker));
}

at::Tensor float_cpu(const at::Tensor& t) { return t.detach().to(at::kCPU, at::kFloat).contiguous(); }

}  // namespace

WebExportSummary export_web_viewer(model::Avatar& avatar, const WebMotion& motion, const WebCamera& camera,
                                   const std::string& folder, bool overwrite) {
  TORCH_CHECK(motion.frames > 0, "the motion has no frames");
  check_web_folder(folder, overwrite);
  at::NoGradGuard no_grad;
  const model::AvatarOutput rest = avatar->forward(rest_pose(avatar), std::nullopt);
  const at::Tensor rest_transforms = rest.skinning_transforms.to(at::kCPU, at::kDouble);
  TORCH_CHECK(at::allclose(rest_transforms, at::eye(4, rest_transforms.options()).expand_as(rest_transforms), 0, 1e-5),
              "the rest pose does not leave the body at rest (its skinning transforms are not the identity)");
  const ViewerInfluences influences = viewer_influences(avatar->skinning_weights());
  const at::Tensor means = float_cpu(rest.canonical_means), log_scales = float_cpu(rest.log_scales);

  const fs::path target = without_trailing_separators(folder);
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code ec;
  fs::create_directories(parent, ec);
  TORCH_CHECK(!ec, "cannot create folder '", parent.string(), "': ", ec.message());
  remove_stale_temporaries(parent.string());
  AtomicFolder out(target.string());
  DataScripts data(out);
  WebExportSummary summary;
  summary.gaussians = avatar->gaussian_count();
  summary.joints = rest.skinning_transforms.size(0);
  summary.influences = influences.joints.size(1);
  summary.frames = motion.frames;
  nlohmann::json manifest = {{"format", "sfgs-web-viewer"},
                             {"version", 1},
                             {"motion", motion.name},
                             {"frames", motion.frames},
                             {"frames_per_second", motion.frames_per_second},
                             {"gaussians", summary.gaussians},
                             {"joints", summary.joints},
                             {"influences", summary.influences},
                             {"camera", camera_json(camera)},
                             {"background", {1.0, 1.0, 1.0}},
                             {"splatting", splatting_json()},
                             {"weight_total", kWeightTotal},
                             {"colour_levels", kColourLevels},
                             {"min_normal_length", kMinNormalLength}};
  // Without shading the colours are the albedo: the viewer's factor is then 1.
  const at::Tensor coefficients = avatar->shading_coefficients();
  if (coefficients.defined()) {
    const at::Tensor c = float_cpu(coefficients);
    manifest["shading"] = std::vector<float>(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
  } else {
    manifest["shading"] = nullptr;
  }
  nlohmann::json& buffers = manifest["buffers"];
  buffers["means"] = data.add(means);
  buffers["log_scales"] = data.add(log_scales);
  buffers["mesh"] = data.add(float_cpu(rest.posed_vertices));
  buffers["faces"] = data.add(avatar->faces().to(at::kCPU, at::kInt));
  buffers["albedo"] = data.add((float_cpu(rest.albedo).clamp(0, 1) * kColourLevels).round().to(at::kByte));
  buffers["opacities"] = data.add((float_cpu(rest.opacities).clamp(0, 1) * kColourLevels).round().to(at::kByte));
  buffers["joints"] = data.add(influences.joints);
  buffers["weights"] = data.add(influences.weights);
  // The sampling record (model/sampling_filter.h), which the viewer's shader widens finer views with, as sfgs does.
  if (avatar->sampling_record().defined()) buffers["sampling"] = data.add(float_cpu(avatar->sampling_record()));
  summary.static_bytes = int64_t(data.pending_bytes());
  data.close("static");

  // Per frame: the joint transforms, and the posed means and log scales as quantised offsets from what the viewer's
  // skinning of the rest pose gives.
  nlohmann::json& frames = manifest["frame_buffers"];
  const at::Tensor rest_means = means.to(at::kDouble);
  for (int64_t f = 0; f < motion.frames; ++f) {
    const model::AvatarOutput posed = motion.pose(f);
    if (posed.colour_offset.defined())
      summary.note =
          "the colour offset (colour_offset_on_new_motions) is left out: the viewer's colours are the "
          "albedo times the shading";
    const at::Tensor transforms = float_cpu(posed.skinning_transforms).slice(1, 0, 3).reshape({-1, 12});
    const at::Tensor blend = blended_transforms(influences, transforms);
    const at::Tensor skinned =
        at::matmul(blend.slice(2, 0, 3), rest_means.unsqueeze(2)).squeeze(2) + blend.select(2, 3);
    const at::Tensor offset = float_cpu(posed.means).to(at::kDouble) - skinned;
    summary.largest_offset = std::max(summary.largest_offset, offset.norm(2, 1).max().item<double>());
    const Quantised mean_offsets = quantise(offset, kOffsetLevels, at::kChar);
    const Quantised log_scale_offsets =
        quantise(float_cpu(posed.log_scales).to(at::kDouble) - log_scales.to(at::kDouble), kLogScaleLevels, at::kChar);
    const size_t before = data.pending_bytes();
    frames.push_back({{"transforms", data.add(transforms)},
                      {"mean_offsets", data.add(mean_offsets.values)},
                      {"mean_step", mean_offsets.step},
                      {"log_scale_offsets", data.add(log_scale_offsets.values)},
                      {"log_scale_step", log_scale_offsets.step}});
    summary.frame_bytes = int64_t(data.pending_bytes() - before);
    if (data.pending_bytes() >= size_t(kWebDataFileBytes) || f + 1 == motion.frames) {
      char name[32];
      std::snprintf(name, sizeof(name), "frames_%03zu", data.files().size() - 1);
      data.close(name);
    }
  }
  manifest["files"] = data.files();
  // Every file the folder gets, so that a later --force can tell them from files a user added.
  nlohmann::json written = data.files();
  for (const WebAsset& asset : web_assets()) written.push_back(asset.name);
  manifest["written"] = written;
  const std::string manifest_script = "var sfgsExport = " + manifest.dump() + ";\nvar sfgsData = [];\n";
  out.add(kManifestFile, text_bytes(manifest_script));
  summary.folder_bytes = data.written_bytes() + int64_t(manifest_script.size());
  for (const WebAsset& asset : web_assets()) {
    std::vector<unsigned char> bytes(asset.bytes, asset.bytes + asset.size);
    if (std::string(asset.name) == "index.html")
      bytes = text_bytes(index_html(std::string(bytes.begin(), bytes.end()), data.files()));
    out.add(asset.name, bytes);
    summary.folder_bytes += int64_t(bytes.size());
  }
  out.commit(overwrite);
  return summary;
}

}  // namespace sfgs::train
