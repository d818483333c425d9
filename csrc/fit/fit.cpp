#include "fit/fit.h"

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/cuda.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <nlohmann/json.hpp>

#include "body/procedural_body.h"
#include "body/wholebody_keypoints.h"
#include "common/atomic_file.h"
#include "data/neuman.h"
#include "data/neuman_writer.h"
#include "fit/fit_accuracy.h"
#include "fit/fit_input.h"
#include "fit/fitter.h"

namespace sfgs::fit {
namespace fs = std::filesystem;

namespace {

constexpr const char* kFitsFolder = "smplx_optimized";
constexpr const char* kLogFile = "fit_log.jsonl";
constexpr const char* kReportFile = "fit_report.json";

c10::Device fit_device(const std::string& name) {
  TORCH_CHECK(name == "cpu" || name == "cuda", "--device: expected cpu or cuda, got '", name, "'");
  TORCH_CHECK(name == "cpu" || torch::cuda::is_available(), "--device cuda: this build or machine has no CUDA device");
  return name == "cpu" ? c10::Device(at::kCPU) : c10::Device(at::kCUDA, 0);
}

nlohmann::json accuracy_json(const FitAccuracy& a) {
  return {{"reference", a.reference},
          {"frames", a.frames},
          {"mpjpe_mm", a.mpjpe_mm},
          {"mpjpe_absolute_mm", a.mpjpe_absolute_mm},
          {"pa_mpjpe_mm", a.pa_mpjpe_mm},
          {"hand_mpjpe_mm", a.hand_mpjpe_mm},
          {"vertex_error_mm", a.vertex_error_mm},
          {"vertex_error_absolute_mm", a.vertex_error_absolute_mm},
          {"pelvis_depth_error_mm", a.depth_error_mm}};
}

nlohmann::json report_json(const FitReport& r, const FitOptions& o) {
  nlohmann::json j{{"data", o.data},
                   {"body", o.body_model.empty() ? "procedural" : o.body_model},
                   {"device", o.device},
                   {"threads", o.threads},
                   {"frames", r.frames},
                   {"cameras", r.camera_source},
                   {"betas_from_data", o.betas_from_data},
                   {"start_from_data", o.start_from_data},
                   {"silhouette", r.silhouette},
                   {"seconds", r.seconds}};
  for (const FitStageSummary& s : r.stages)
    j["stages"].push_back({{"name", s.name}, {"iterations", s.iterations}, {"seconds", s.seconds}, {"loss", s.loss}});
  if (r.accuracy) j["accuracy"] = accuracy_json(*r.accuracy);
  return j;
}

// Makes `out` a NeuMan-layout dataset of the fits: every entry of the video folder but its own fits (and the fit's
// log and report) appears in `out` as a link to it, so `sfgs train --data OUT` reads the video with these fits.
// Entries `out` already holds stay as they are. Returns whether `out` is such a dataset now.
bool link_video_beside_fits(const std::string& data, const std::string& out) {
  const fs::path video = fs::absolute(data).lexically_normal();
  if (!fs::exists(video / "sparse" / "images.txt")) return false;  // not a NeuMan folder: nothing train could read
  for (const fs::directory_entry& e : fs::directory_iterator(video)) {
    const std::string name = e.path().filename().string();
    if (name == kFitsFolder || name == kLogFile || name == kReportFile) continue;
    const fs::path link = fs::path(out) / name;
    if (fs::exists(fs::symlink_status(link))) continue;
    if (e.is_directory())
      fs::create_directory_symlink(e.path(), link);
    else
      fs::create_symlink(e.path(), link);
  }
  return true;
}

// Sets LibTorch's intra-op threads for the scope and restores them after.
class IntraOpThreads {
 public:
  explicit IntraOpThreads(int64_t threads) : previous_(at::get_num_threads()) { at::set_num_threads(int(threads)); }
  ~IntraOpThreads() { at::set_num_threads(previous_); }
  IntraOpThreads(const IntraOpThreads&) = delete;
  IntraOpThreads& operator=(const IntraOpThreads&) = delete;

 private:
  int previous_;
};

}  // namespace

FitReport run_fit(const FitOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  const c10::Device device = fit_device(options.device);
  TORCH_CHECK(options.threads >= 1, "--threads: expected at least 1, got ", options.threads);
  const IntraOpThreads threads(options.threads);
  const std::string out = options.out.empty() ? options.data : options.out;
  const fs::path fits = fs::path(out) / kFitsFolder;
  TORCH_CHECK(options.overwrite || !fs::exists(fits), "sfgs fit: '", fits.string(),
              "' exists; pass --force to replace it, or --out another folder");
  const FitInput input = read_fit_input(options.data, options.focal);
  // The exact fits are read, and checked against the frames, before any work: a bad --truth fails in seconds, and
  // before the fits are written (a rerun then needs no --force).
  const std::optional<ReferenceFits> reference = find_reference_fits(options.data, options.truth);
  if (reference) {
    int64_t shared = 0;
    for (const FitFrame& f : input.frames) shared += int64_t(reference->poses.count(f.number));
    TORCH_CHECK(shared > 0, options.truth.empty() ? "the exact fits '" : "--truth: the exact fits '", reference->source,
                "' share no frame with the ", input.frames.size(), " frames of '", options.data, "'");
  }
  const body::SmplxModelData model = body::smplx_model_or_procedural(options.body_model);
  const body::WholeBodyKeypointMap keypoint_map = body::wholebody_keypoint_map(model, options.body_model);
  fs::create_directories(out);
  std::ofstream log((fs::path(out) / kLogFile).string(), std::ios::trunc);
  TORCH_CHECK(log.good(), "sfgs fit: cannot write '", (fs::path(out) / kLogFile).string(), "'");

  FitSettings settings;
  settings.iterations = options.iterations;
  settings.use_masks = options.use_masks;
  settings.log_every = options.log_every;
  if (options.betas_from_data) {
    TORCH_CHECK(input.betas.defined(), "--betas-from-data: '", options.data,
                "' holds no shape "
                "(smplx_optimized/shape_param.json or dataset.json betas)");
    settings.known_betas = input.betas;
  }
  if (options.start_from_data) {
    const fs::path given = fs::path(options.data) / kFitsFolder;
    std::vector<body::SmplxPose> fits;
    for (const FitFrame& f : input.frames)
      fits.push_back(
          data::read_exavatar_pose((given / "smplx_params" / (std::to_string(f.number) + ".json")).string()));
    TORCH_CHECK(input.betas.defined(), "--start-from-data: '", (given / "shape_param.json").string(), "' is missing");
    settings.initial_fits = body::SmplxPose::stack(fits);
    settings.initial_betas = input.betas;
  }
  settings.log = [&](const nlohmann::json& line) { log << line.dump() << "\n" << std::flush; };
  if (!options.quiet) settings.progress = [](const std::string& line) { std::printf("%s\n", line.c_str()); };
  if (!options.quiet)
    std::printf("sfgs fit: %zu frames of %s on %s (cameras: %s; keypoint definition: %s%s)\n", input.frames.size(),
                options.data.c_str(), options.device.c_str(), input.camera_source.c_str(),
                keypoint_map.definition().c_str(),
                keypoint_map.face_from_embedding() ? ", model's face landmarks" : "");
  const FitResult result = fit_smplx(model, keypoint_map, input, device, settings);

  std::map<int64_t, body::SmplxPose> poses;
  for (size_t i = 0; i < input.frames.size(); ++i) poses[input.frames[i].number] = result.poses.frame(int64_t(i));
  data::write_smplx_parameter_folder(fits.string(), result.betas, poses, {}, options.overwrite);
  const bool separate = fs::absolute(out).lexically_normal() != fs::absolute(options.data).lexically_normal();

  FitReport report;
  report.frames = int64_t(input.frames.size());
  report.camera_source = input.camera_source;
  report.silhouette = result.silhouette;
  report.stages = result.stages;
  report.trainable_dataset = !separate || link_video_beside_fits(options.data, out);
  if (reference) report.accuracy = measure_accuracy(model, poses, result.betas, *reference);
  report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const nlohmann::json j = report_json(report, options);
  log << nlohmann::json{{"report", j}}.dump() << "\n";
  const std::string text = j.dump(1) + "\n";
  write_file_atomically((fs::path(out) / kReportFile).string(), {text.begin(), text.end()}, true);
  return report;
}

}  // namespace sfgs::fit
