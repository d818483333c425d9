// `sfgs train`, `sfgs ablate` and `sfgs demo` (synthesise, train, evaluate, render).
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/evaluation_report.h"
#include "cli/plot.h"
#include "common/atomic_file.h"
#include "data/synthetic.h"
#include "train/evaluate.h"
#include "train/trainer.h"

namespace sfgs::cli {
namespace fs = std::filesystem;

namespace {

train::TrainConfig load_config(Arguments& args, const std::string& fallback_file) {
  const std::string file = args.text("config", fallback_file);
  train::TrainConfig config = file.empty() ? train::TrainConfig{} : train::TrainConfig::from_yaml_file(file);
  config.schedule.iterations = args.integer("iterations", config.schedule.iterations, 1, 100000000);
  config.device = args.text("device", config.device);
  config.validate();
  return config;
}

// Prints the summary and writes the run's run-time-versus-error curve (curve.csv, curve.png) beside its log.
void finish_training(const train::RunFolder& run, const train::TrainSummary& s) {
  char validation[64] = "no validation frames";
  if (!std::isnan(s.validation_psnr)) std::snprintf(validation, sizeof(validation), "validation PSNR %.2f dB", s.validation_psnr);
  std::printf("  %lld iterations, %.1f s of training steps (%.1f ms/iteration); final loss %.4f; %s\n",
              (long long)s.iterations, s.training_seconds,
              1000.0 * s.training_seconds / double(std::max<int64_t>(s.iterations, 1)), s.final_loss, validation);
  const std::string csv = (fs::path(run.path) / "curve.csv").string(), png = (fs::path(run.path) / "curve.png").string();
  const std::vector<train::ErrorCurvePoint> curve = train::write_error_curve_csv(run, csv);
  const bool plotted = write_error_curve_plot(curve, png, true);
  std::printf("  run-time versus error: %s%s%s\n", csv.c_str(), plotted ? ", " : "", plotted ? png.c_str() : "");
}

train::AvatarEvaluation evaluate_run(const train::RunFolder& run, const data::Dataset& dataset,
                                     const std::string& device, const std::string& images, bool overwrite) {
  train::TrainedAvatar t = train::load_trained_avatar(run, device == "cuda" ? at::kCUDA : at::kCPU);
  t.avatar->eval();
  t.avatar->cache_static_features();
  const train::AvatarEvaluation e =
      train::evaluate_avatar(dataset, data::Split::kTest, t.avatar, metrics::EvaluationOptions{}, images, overwrite);
  const std::string text = evaluation_json(e).dump(1) + "\n";
  write_file_atomically((fs::path(run.path) / "metrics.json").string(), std::vector<unsigned char>(text.begin(), text.end()), true);
  return e;
}

std::string default_config(const char* name) {
  const fs::path p = fs::path(SFGS_CONFIG_DIR) / name;
  return fs::exists(p) ? p.string() : "";
}

}  // namespace

int run_train(Arguments& args) {
  const std::string data_folder = args.required("data");
  const train::RunFolder run{args.required("out")};
  train::TrainConfig config = load_config(args, default_config("default.yaml"));
  train::TrainOptions options;
  options.resume = args.flag("resume");
  options.overwrite = args.flag("force");
  options.progress = !args.flag("quiet");
  options.stop_at = args.integer("stop-at", 0, 0, 100000000);
  args.finish();
  const data::Dataset dataset = data::read_dataset(data_folder);
  std::printf("sfgs train: %s (%lld frames, %lld for training) -> %s on %s\n", dataset.source.c_str(),
              (long long)dataset.size(), (long long)dataset.split(data::Split::kTrain).size(), run.path.c_str(),
              config.device.c_str());
  finish_training(run, train::train_avatar(dataset, config, run, options));
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
      {"no_color_offset", [](model::AvatarConfig& a) { a.use_color_offset = false; }},
      {"no_hand_residual", [](model::AvatarConfig& a) { a.use_hand_residual = false; }},
      {"no_face_planes", [](model::AvatarConfig& a) { a.use_face_planes = false; }},
  };
  nlohmann::json table = nlohmann::json::array();
  std::string markdown = "| variant | PSNR | SSIM | LPIPS | train s |\n|---|---|---|---|---|\n";
  for (const auto& [name, change] : variants) {
    train::TrainConfig config = base;
    change(config.avatar);
    const train::RunFolder run{(fs::path(out) / name).string()};
    train::TrainOptions options;
    options.overwrite = force;
    std::printf("sfgs ablate: %s\n", name.c_str());
    const train::TrainSummary s = train::train_avatar(dataset, config, run, options);
    finish_training(run, s);
    const train::AvatarEvaluation e = evaluate_run(run, dataset, config.device, "", force);
    char row[256];
    std::snprintf(row, sizeof(row), "| %s | %.2f | %.4f | %s | %.0f |\n", name.c_str(), e.summary.psnr, e.summary.ssim,
                  e.summary.lpips ? std::to_string(*e.summary.lpips).c_str() : "n/a", s.training_seconds);
    markdown += row;
    nlohmann::json j = evaluation_json(e);
    j.erase("per_frame");
    j["variant"] = name;
    j["train_seconds"] = s.training_seconds;
    table.push_back(j);
  }
  const std::string json_text = table.dump(1) + "\n";
  write_file_atomically((fs::path(out) / "ablation.json").string(), std::vector<unsigned char>(json_text.begin(), json_text.end()), force);
  write_file_atomically((fs::path(out) / "ablation.md").string(), std::vector<unsigned char>(markdown.begin(), markdown.end()), force);
  std::printf("%s", markdown.c_str());
  return 0;
}

int run_demo(Arguments& args) {
  const std::string out = args.text("out", "sfgs_demo");
  train::TrainConfig config = load_config(args, default_config("demo.yaml"));
  const bool force = args.flag("force");
  args.finish();
  TORCH_CHECK(force || !fs::exists(out), "'", out, "' exists: pass --force to replace the demo there");
  data::SyntheticVideoOptions video;
  video.frames = 40;
  video.width = 96;
  video.height = 96;
  video.overwrite = true;
  const std::string data_folder = (fs::path(out) / "data").string();
  std::printf("sfgs demo 1/4: synthesising %lld frames of %lld x %lld into %s\n", (long long)video.frames,
              (long long)video.width, (long long)video.height, data_folder.c_str());
  const data::Dataset dataset = data::write_synthetic_video(data_folder, video);
  const train::RunFolder run{(fs::path(out) / "run").string()};
  std::printf("sfgs demo 2/4: training %lld iterations on %s\n", (long long)config.schedule.iterations, config.device.c_str());
  train::TrainOptions options;
  options.overwrite = true;
  finish_training(run, train::train_avatar(dataset, config, run, options));
  std::printf("sfgs demo 3/4: evaluating the test frames (ExAvatar/SFGS protocol)\n");
  const train::AvatarEvaluation e =
      evaluate_run(run, dataset, config.device, (fs::path(out) / "test_renders").string(), true);
  std::printf("  %s\n", metrics::to_string(e.summary).c_str());
  std::printf("sfgs demo 4/4: rendering a novel-view, novel-pose video\n");
  const std::string render_folder = (fs::path(out) / "novel").string();
  Arguments render_args({"--run", run.path, "--out", render_folder, "--frames", "24", "--force"}, {"force"});
  run_render(render_args);
  std::printf("sfgs demo: done. Test PSNR %.2f dB, SSIM %.4f; test renders in %s, novel views in %s\n", e.summary.psnr,
              e.summary.ssim, (fs::path(out) / "test_renders").string().c_str(), render_folder.c_str());
  return 0;
}

}  // namespace sfgs::cli
