#include "train/results.h"

#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>

#include <c10/util/Exception.h>

#include "common/atomic_file.h"
#include "common/checksum.h"

namespace sfgs::train {
namespace fs = std::filesystem;

namespace {

constexpr const char* kMetricsPrefix = "metrics_";
constexpr const char* kImagesPrefix = "eval_images_";
constexpr size_t kDigestChunkBytes = size_t(1) << 20;

// "test", "test_fitted_poses", "test_<fingerprint>", "test_fitted_poses_<fingerprint>".
std::string result_stem(const ResultOrigin& o) {
  std::string stem = data::split_name(o.split);
  if (!o.variant.empty()) stem += "_" + o.variant;
  if (!o.own_dataset) stem += "_" + o.dataset_fingerprint;
  return stem;
}

// Before results carried their provenance, eval wrote metrics.json and eval_images/: derived outputs all the same.
constexpr const char* kUnsplitMetrics = "metrics.json";
constexpr const char* kUnsplitImages = "eval_images";

bool is_metrics_file(const fs::path& p) {
  const std::string name = p.filename().string();
  return name == kUnsplitMetrics || (name.rfind(kMetricsPrefix, 0) == 0 && p.extension() == ".json");
}

bool is_images_folder(const fs::path& p) {
  const std::string name = p.filename().string();
  return name == kUnsplitImages || name.rfind(kImagesPrefix, 0) == 0;
}

// The images' folder of a metrics file ("metrics_X.json" -> "eval_images_X", "metrics.json" -> "eval_images").
fs::path images_of(const fs::path& metrics) {
  if (metrics.filename() == kUnsplitMetrics) return metrics.parent_path() / kUnsplitImages;
  const std::string stem = metrics.stem().string().substr(std::string(kMetricsPrefix).size());
  return metrics.parent_path() / (kImagesPrefix + stem);
}

// Removes the PNG files of an images folder, and the folder when that empties it: nothing else a user put there.
void remove_images(const fs::path& folder) {
  if (!fs::is_directory(folder)) return;
  for (const fs::directory_entry& e : fs::directory_iterator(folder))
    if (e.is_regular_file() && e.path().extension() == ".png") fs::remove(e.path());
  if (fs::is_empty(folder)) fs::remove(folder);
}

std::string utc_now() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm utc{};
  gmtime_r(&now, &utc);
  char text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

}  // namespace

std::string metrics_file_name(const ResultOrigin& origin) { return kMetricsPrefix + result_stem(origin) + ".json"; }
std::string images_folder_name(const ResultOrigin& origin) { return kImagesPrefix + result_stem(origin); }

std::string checkpoint_digest(const std::string& checkpoint_file) {
  std::ifstream in(checkpoint_file, std::ios::binary);
  TORCH_CHECK(in, "cannot open checkpoint '", checkpoint_file, "' to take its digest");
  std::vector<char> chunk(kDigestChunkBytes);
  uint32_t crc = 0;
  while (in) {
    in.read(chunk.data(), std::streamsize(chunk.size()));
    crc = crc32_of(chunk.data(), size_t(in.gcount()), crc);
  }
  char hex[16];
  std::snprintf(hex, sizeof(hex), "%08x", crc);
  return hex;
}

nlohmann::json provenance_json(const ResultOrigin& o) {
  return {{"split", data::split_name(o.split)},
          {"variant", o.variant.empty() ? "plain" : o.variant},
          {"dataset", o.dataset},
          {"dataset_fingerprint", o.dataset_fingerprint},
          {"own_dataset", o.own_dataset},
          {"checkpoint_iteration", o.checkpoint_iteration},
          {"checkpoint_crc32", o.checkpoint_crc32},
          {"command", o.command},
          {"written_at", utc_now()}};
}

std::string write_result(const RunFolder& run, const ResultOrigin& origin, nlohmann::json metrics) {
  const std::string now = checkpoint_digest(run.checkpoint_file());
  TORCH_CHECK(now == origin.checkpoint_crc32, "the checkpoint of run '", run.path,
              "' changed while it was being evaluated (a training wrote it): not writing ", metrics_file_name(origin),
              " for the old one; evaluate again once the training is done");
  metrics["provenance"] = provenance_json(origin);
  const std::string path = (fs::path(run.path) / metrics_file_name(origin)).string();
  const std::string text = metrics.dump(1) + "\n";
  write_file_atomically(path, std::vector<unsigned char>(text.begin(), text.end()), true);
  return path;
}

std::vector<std::string> stale_results(const RunFolder& run, const std::string& current) {
  std::vector<std::string> stale;
  if (!fs::is_directory(run.path)) return stale;
  for (const fs::directory_entry& e : fs::directory_iterator(run.path)) {
    if (!e.is_regular_file() || !is_metrics_file(e.path())) continue;
    std::string recorded;
    try {
      std::ifstream in(e.path());
      const nlohmann::json j = nlohmann::json::parse(in);
      recorded = j.at("provenance").at("checkpoint_crc32").get<std::string>();
    } catch (const std::exception&) {
      // Unreadable, or written before results carried their provenance: nothing says which checkpoint it measured.
    }
    if (recorded.empty() || recorded != current) stale.push_back(e.path().filename().string());
  }
  return stale;
}

std::vector<std::string> remove_stale_results(const RunFolder& run) {
  const std::vector<std::string> stale =
      stale_results(run, fs::exists(run.checkpoint_file()) ? checkpoint_digest(run.checkpoint_file()) : "");
  for (const std::string& name : stale) {
    const fs::path metrics = fs::path(run.path) / name;
    remove_images(images_of(metrics));
    fs::remove(metrics);
  }
  return stale;
}

void remove_derived_outputs(const RunFolder& run) {
  if (!fs::is_directory(run.path)) return;
  std::vector<fs::path> found;
  for (const fs::directory_entry& e : fs::directory_iterator(run.path)) {
    if ((e.is_regular_file() && is_metrics_file(e.path())) || (e.is_directory() && is_images_folder(e.path())))
      found.push_back(e.path());
  }
  for (const fs::path& p : found) {
    if (fs::is_directory(p))
      remove_images(p);
    else
      fs::remove(p);
  }
}

}  // namespace sfgs::train
