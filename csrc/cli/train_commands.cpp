// `sfgs train`, `sfgs ablate` and `sfgs demo` (synthesise, train, evaluate, render).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <optional>
#include <stdexcept>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/evaluation_report.h"
#include "cli/plot.h"
#include "common/atomic_file.h"
#include "train/constants.h"
#include "common/folder_lock.h"
#include "data/synthetic.h"
#include "train/checkpoint.h"
#include "train/evaluate.h"
#include "train/results.h"
#include "train/rounds.h"
#include "train/trainer.h"

namespace sfgs::cli {
namespace fs = std::filesystem;

namespace {

// --iterations and --device on top of a config.
void apply_overrides(Arguments& args, train::TrainConfig& config) {
  config.schedule.iterations = args.integer("iterations", config.schedule.iterations, 1, kMaxIterations);
  config.device = args.text("device", config.device);
  config.validate();
}

train::TrainConfig load_config(Arguments& args, const std::string& fallback_file) {
  const std::string file = args.text("config", fallback_file);
  train::TrainConfig config = file.empty() ? train::TrainConfig{} : train::TrainConfig::from_yaml_file(file);
  apply_overrides(args, config);
  return config;
}

// Says what this call did: which iterations it ran, where the run stands, its last loss and validation, and writes
// the run-time-versus-error curve (curve.csv, curve.png) beside the log.
void finish_training(const train::TrainSummary& s, int64_t scheduled) {
  const train::RunFolder run{s.folder};
  if (s.rounds > 1)
    std::printf("  round %lld of %lld, in %s\n", (long long)s.round, (long long)s.rounds, run.path.c_str());
  if (s.steps == 0) {
    std::printf(
        "  run '%s' is already at iteration %lld of %lld: nothing to do (raise --iterations to train further)\n",
        run.path.c_str(), (long long)s.iterations, (long long)scheduled);
    return;
  }
  std::string validation = "no validation frames in the dataset";
  if (!std::isnan(s.validation_psnr)) {
    char text[64];
    std::snprintf(text, sizeof(text), "validation PSNR %.2f dB", s.validation_psnr);
    validation = text;
  } else if (s.has_validation_frames) {
    validation = "not validated in this call";
  }
  std::printf(
      "  iterations %lld-%lld (%lld steps, %.1f ms each); the run is %s at iteration %lld of %lld; final loss "
      "%.4f; %s\n",
      (long long)s.first_iteration + 1, (long long)s.iterations, (long long)s.steps,
      1000.0 * s.step_seconds / double(s.steps), s.finished ? "finished" : "paused", (long long)s.iterations,
      (long long)scheduled, s.final_loss, validation.c_str());
  std::printf("  %.1f s of training steps over the whole run\n", s.training_seconds);
  const std::string csv = (fs::path(run.path) / "curve.csv").string(),
                    png = (fs::path(run.path) / "curve.png").string();
  const std::vector<train::ErrorCurvePoint> curve = train::write_error_curve_csv(run, csv);
  const bool plotted = write_error_curve_plot(curve, png, true);
  std::printf("  run-time versus error: %s%s%s\n", csv.c_str(), plotted ? ", " : "", plotted ? png.c_str() : "");
}

// Evaluates the run on the test split (metrics_test.json) and, when the dataset has one, on the validation split
// (metrics_val.json): with a novel-motion test split, validation is the interleaved (replay) number beside the
// novel-pose one.
struct RunEvaluation {
  train::AvatarEvaluation test;
  std::optional<train::AvatarEvaluation> val;
};

RunEvaluation evaluate_run(const train::RunFolder& run, const data::Dataset& dataset, const std::string& device,
                           const std::string& images, bool overwrite, const std::string& command) {
  const FolderLock lock(run.path, "eval");
  train::ResultOrigin origin;
  origin.checkpoint_crc32 = train::checkpoint_digest(run.checkpoint_file());
  train::TrainedAvatar t = train::load_trained_avatar(run, device == "cuda" ? at::kCUDA : at::kCPU);
  origin.dataset = train::absolute_dataset_path(dataset);
  origin.dataset_fingerprint = dataset.fingerprint();
  origin.checkpoint_iteration = t.iteration;
  origin.command = command;
  t.avatar->eval();
  t.avatar->cache_static_features();
  RunEvaluation e;
  e.test =
      train::evaluate_avatar(dataset, data::Split::kTest, t.avatar, metrics::EvaluationOptions{}, images, overwrite);
  train::write_result(run, origin, evaluation_json(e.test));
  if (!dataset.split(data::Split::kVal).empty()) {
    e.val = train::evaluate_avatar(dataset, data::Split::kVal, t.avatar, metrics::EvaluationOptions{}, "", overwrite);
    origin.split = data::Split::kVal;
    train::write_result(run, origin, evaluation_json(*e.val));
  }
  return e;
}

std::string default_config(const char* name) {
  const fs::path p = fs::path(SFGS_CONFIG_DIR) / name;
  return fs::exists(p) ? p.string() : "";
}

}  // namespace

int run_train(Arguments& args) {
  const train::RunFolder run{args.required("out")};
  train::TrainOptions options;
  options.resume = args.flag("resume");
  options.overwrite = args.flag("force");
  options.progress = !args.flag("quiet");
  options.stop_at = args.integer("stop-at", 0, 1, kMaxIterations);  // 0: not given
  // A run folder stands for its refined fits.
  options.start_fits = train::start_fits_file(args.text("start-fits", ""));
  std::string data_folder = args.text("data", "");
  train::TrainConfig config;
  const std::string resumed_checkpoint = train::resumable_checkpoint(run);
  if (options.resume && (!resumed_checkpoint.empty() || fs::exists(run.config_file()))) {
    // The run's own config and data unless told otherwise; train_avatar refuses changes that are not safe.
    std::optional<train::CheckpointReader> checkpoint;
    if (!resumed_checkpoint.empty()) checkpoint.emplace(resumed_checkpoint);
    const std::string own = fs::exists(run.config_file()) ? run.config_file() : "";
    const std::string file = args.text("config", own);
    config = file.empty()  ? checkpoint->info().config
             : file == own ? train::TrainConfig::from_stored_yaml_file(own)  // written with the run, as its checkpoint
                           : train::TrainConfig::from_yaml_file(file);
    apply_overrides(args, config);
    if (data_folder.empty()) {
      TORCH_CHECK(checkpoint, "run '", run.path, "' has no checkpoint yet to say which dataset it trains on; pass ",
                  "--data with the dataset's folder");
      data_folder = checkpoint->info().dataset;
      TORCH_CHECK(fs::is_directory(data_folder), "run '", run.path, "' was trained on dataset '", data_folder,
                  "', which is not there (moved or deleted); pass --data with the dataset's folder");
    }
  } else {
    config = load_config(args, default_config("default.yaml"));
    if (data_folder.empty() && options.resume)
      throw std::invalid_argument("--resume: '" + run.path + "' holds no run to resume (no checkpoint.pt or " +
                                  "config.yaml); start one with --data DATASET");
    if (data_folder.empty()) throw std::invalid_argument("missing required option --data");
  }
  args.finish();
  // A run inside its dataset would mix its files into the dataset's (and a --force could remove them).
  const fs::path data_path = fs::weakly_canonical(data_folder), run_path = fs::weakly_canonical(run.path);
  const bool inside =
      std::mismatch(data_path.begin(), data_path.end(), run_path.begin(), run_path.end()).first == data_path.end();
  TORCH_CHECK(!inside, "--out '", run.path, "' lies in the dataset folder '", data_folder,
              "': give the run a folder of its own, outside the dataset");
  const data::Dataset dataset = data::read_dataset(data_folder);
  std::printf("sfgs train: %s (%lld frames, %lld for training) -> %s on %s\n", dataset.source.c_str(),
              (long long)dataset.size(), (long long)dataset.split(data::Split::kTrain).size(), run.path.c_str(),
              config.device.c_str());
  finish_training(train::train_avatar(dataset, config, run, options), config.schedule.iterations);
  return 0;
}

int run_ablate(Arguments& args) {
  const std::string data_folder = args.required("data");
  const std::string out = args.required("out");
  const train::TrainConfig base = load_config(args, default_config("default.yaml"));
  const bool force = args.flag("force");
  args.finish();
  const data::Dataset dataset = data::read_dataset(data_folder);
  const std::vector<std::pair<std::string, std::function<void(model::AvatarConfig&)>>> variants = {
      {"full", [](model::AvatarConfig&) {}},
      {"no_hexplane", [](model::AvatarConfig& a) { a.use_hexplane = false; }},
      {"no_structure_offset", [](model::AvatarConfig& a) { a.use_structure_offset = false; }},
      {"no_colour_offset", [](model::AvatarConfig& a) { a.use_colour_offset = false; }},
      {"no_hand_residual", [](model::AvatarConfig& a) { a.use_hand_residual = false; }},
      {"no_face_planes", [](model::AvatarConfig& a) { a.use_face_planes = false; }},
      {"no_shading", [](model::AvatarConfig& a) { a.use_shading = false; }},
  };
  nlohmann::json table = nlohmann::json::array();
  std::string markdown = "| variant | test PSNR | SSIM | LPIPS | val PSNR | train s |\n|---|---|---|---|---|---|\n";
  for (const auto& [name, change] : variants) {
    train::TrainConfig config = base;
    change(config.avatar);
    const train::RunFolder run{(fs::path(out) / name).string()};
    train::TrainOptions options;
    options.overwrite = force;
    std::printf("sfgs ablate: %s\n", name.c_str());
    const train::TrainSummary s = train::train_avatar(dataset, config, run, options);
    finish_training(s, config.schedule.iterations);
    const RunEvaluation both = evaluate_run(run, dataset, config.device, "", force, "sfgs ablate " + args.line());
    const train::AvatarEvaluation& e = both.test;
    char row[256];
    std::snprintf(row, sizeof(row), "| %s | %.2f | %.4f | %s | %s | %.0f |\n", name.c_str(), e.summary.psnr,
                  e.summary.ssim, e.summary.lpips ? std::to_string(*e.summary.lpips).c_str() : "n/a",
                  both.val ? std::to_string(both.val->summary.psnr).c_str() : "n/a", s.training_seconds);
    markdown += row;
    nlohmann::json j = evaluation_json(e);
    j.erase("per_frame");
    if (both.val) j["val_psnr"] = both.val->summary.psnr;
    j["variant"] = name;
    j["train_seconds"] = s.training_seconds;
    table.push_back(j);
  }
  const std::string json_text = table.dump(1) + "\n";
  write_file_atomically((fs::path(out) / "ablation.json").string(),
                        std::vector<unsigned char>(json_text.begin(), json_text.end()), force);
  write_file_atomically((fs::path(out) / "ablation.md").string(),
                        std::vector<unsigned char>(markdown.begin(), markdown.end()), force);
  std::printf("%s", markdown.c_str());
  return 0;
}

int run_demo(Arguments& args) {
  const std::string out = args.text("out", "sfgs_demo");
  train::TrainConfig config = load_config(args, default_config("demo.yaml"));
  const bool force = args.flag("force");
  args.finish();
  TORCH_CHECK(force || !fs::exists(out), "'", out, "' exists: pass --force to replace the demo there");
  // The novel-motion benchmark in small: trained on some motions, tested on others (docs/results.md).
  data::SyntheticVideoOptions video;
  video.motions = {"walk", "wave", "turn"};
  video.test_motions = {"overhead", "bend", "guard", "sit"};
  video.frames = 20;
  video.frames_per_second = 10;
  video.width = 96;
  video.height = 96;
  video.overwrite = true;
  const std::string data_folder = (fs::path(out) / "data").string();
  const auto listed = [](const std::vector<std::string>& motions) {
    std::string text;
    for (const std::string& m : motions) text += (text.empty() ? "" : ", ") + m;
    return text;
  };
  std::printf("sfgs demo 1/4: synthesising %lld frames of %lld x %lld into %s: %s to train on; %s to test on\n",
              (long long)(video.frames * int64_t(video.motions.size() + video.test_motions.size())),
              (long long)video.width, (long long)video.height, data_folder.c_str(), listed(video.motions).c_str(),
              listed(video.test_motions).c_str());
  const data::Dataset dataset = data::write_synthetic_video(data_folder, video);
  const train::RunFolder run{(fs::path(out) / "run").string()};
  std::printf("sfgs demo 2/4: training %lld iterations on %s\n", (long long)config.schedule.iterations,
              config.device.c_str());
  train::TrainOptions options;
  options.overwrite = true;
  finish_training(train::train_avatar(dataset, config, run, options), config.schedule.iterations);
  std::printf(
      "sfgs demo 3/4: evaluating the new motions (test) and the held-out frames of the training motions "
      "(val), ExAvatar/SFGS protocol\n");
  const RunEvaluation e = evaluate_run(run, dataset, config.device, (fs::path(out) / "test_renders").string(), true,
                                       "sfgs demo " + args.line());
  std::printf("  new motions:      %s\n%s", metrics::to_string(e.test.summary).c_str(), group_lines(e.test).c_str());
  std::printf("  held-out frames:  %s\n", metrics::to_string(e.val->summary).c_str());
  std::printf("sfgs demo 4/4: rendering a novel-view, novel-pose video\n");
  const std::string render_folder = (fs::path(out) / "novel").string();
  Arguments render_args({"--run", run.path, "--out", render_folder, "--frames", "24", "--force"}, {"force"});
  run_render(render_args);
  std::printf(
      "sfgs demo: done. New-motion PSNR %.2f dB, SSIM %.4f (held-out frames of the training motions: %.2f dB); "
      "test renders in %s, novel views in %s\n",
      e.test.summary.psnr, e.test.summary.ssim, e.val->summary.psnr, (fs::path(out) / "test_renders").string().c_str(),
      render_folder.c_str());
  return 0;
}

}  // namespace sfgs::cli
