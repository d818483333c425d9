// Commands that use a trained avatar: `sfgs eval`, `sfgs render` (orbit views in novel poses, PNG and MP4) and
// `sfgs export` (.ply).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/evaluation_report.h"
#include "cli/video.h"
#include "common/atomic_file.h"
#include "data/image_io.h"
#include "data/synthetic.h"
#include "train/evaluate.h"
#include "train/run_folder.h"

namespace sfgs::cli {
namespace fs = std::filesystem;

namespace {

constexpr double kTwoPi = 6.283185307179586;
constexpr int64_t kNovelMotionOffset = 1000;  // synthetic-motion frames far past any training video: novel poses

// --device, or else the device the run was trained on where this build has it, else the CPU.
at::Device pick_device(const std::string& name, const train::RunFolder& run) {
  if (name.empty()) {
    std::string trained_on = "cpu";
    if (fs::exists(run.config_file())) trained_on = train::TrainConfig::from_yaml_file(run.config_file()).device;
    return trained_on == "cuda" && cuda_backend_available() ? at::kCUDA : at::kCPU;
  }
  if (name == "cpu") return at::kCPU;
  if (name == "cuda" && cuda_backend_available()) return at::kCUDA;
  throw std::invalid_argument("--device expects cpu or cuda (with a CUDA build), got '" + name + "'");
}

data::Split parse_split(const std::string& s) {
  if (s == "train") return data::Split::kTrain;
  if (s == "val") return data::Split::kVal;
  if (s == "test") return data::Split::kTest;
  throw std::invalid_argument("--split expects train, val or test, got '" + s + "'");
}

void write_text_atomically(const std::string& path, const std::string& text) {
  write_file_atomically(path, std::vector<unsigned char>(text.begin(), text.end()), true);
}

}  // namespace

nlohmann::json evaluation_json(const train::AvatarEvaluation& e) {
  nlohmann::json j{{"frames", e.summary.frames}, {"psnr", e.summary.psnr}, {"ssim", e.summary.ssim},
                   {"lpips_status", e.summary.lpips_status}, {"render_ms", e.render_milliseconds}};
  if (e.summary.lpips) j["lpips"] = *e.summary.lpips;
  if (e.summary.tc_lpips) j["tc_lpips"] = *e.summary.tc_lpips;
  for (size_t i = 0; i < e.frames.size(); ++i) {
    nlohmann::json f{{"name", e.frame_names[i]}, {"psnr", e.frames[i].psnr}, {"ssim", e.frames[i].ssim}};
    if (e.frames[i].lpips) f["lpips"] = *e.frames[i].lpips;
    j["per_frame"].push_back(f);
  }
  return j;
}

int run_eval(Arguments& args) {
  const train::RunFolder run{args.required("run")};
  const std::string data_folder = args.text("data", "");
  const data::Split split = parse_split(args.text("split", "test"));
  metrics::EvaluationOptions options;
  options.eight_bit_round_trip = args.flag("eight-bit");
  const bool save = args.flag("save-images");
  const bool force = args.flag("force");
  const at::Device device = pick_device(args.text("device", ""), run);
  args.finish();
  train::TrainedAvatar t = train::load_trained_avatar(run, device);
  const data::Dataset dataset = data::read_dataset(data_folder.empty() ? t.dataset : data_folder);
  t.avatar->eval();
  t.avatar->cache_static_features();
  const train::AvatarEvaluation e = train::evaluate_avatar(
      dataset, split, t.avatar, options, save ? (fs::path(run.path) / "eval_images").string() : "", force);
  write_text_atomically((fs::path(run.path) / "metrics.json").string(), evaluation_json(e).dump(1) + "\n");
  std::printf("sfgs eval: %s\n  %s\n  render %.2f ms per frame (avatar + rasterisation); metrics.json in %s\n",
              dataset.source.c_str(), metrics::to_string(e.summary).c_str(), e.render_milliseconds, run.path.c_str());
  return 0;
}

int run_render(Arguments& args) {
  const train::RunFolder run{args.required("run")};
  const std::string out = args.required("out");
  const int64_t frames = args.integer("frames", 48, 1, 100000);
  const std::string motion = args.text("motion", "synthetic");
  const bool force = args.flag("force");
  const at::Device device = pick_device(args.text("device", ""), run);
  args.finish();
  train::TrainedAvatar t = train::load_trained_avatar(run, device);
  const data::Dataset trained_on = data::read_dataset(t.dataset);
  const data::Dataset* poses = nullptr;
  data::Dataset motion_dataset;
  if (motion != "synthetic") {
    motion_dataset = data::read_dataset(motion);
    poses = &motion_dataset;
  }
  fs::create_directories(out);
  t.avatar->eval();
  t.avatar->cache_static_features();
  at::NoGradGuard no_grad;

  // Orbit the subject at the distance of the first training camera, looking at its centre.
  const Camera base = train::render_camera(trained_on.frames[0]);
  const auto centre_out = t.avatar->forward(train::avatar_pose(trained_on, 0, device));
  const at::Tensor centre = centre_out.means.mean(0).cpu().to(at::kDouble);
  const double cx = centre[0].item<double>(), cy = centre[1].item<double>(), cz = centre[2].item<double>();
  const auto& m = base.world_to_camera;
  // Camera centre = -R^T t.
  const double ex = -(m[0] * m[3] + m[4] * m[7] + m[8] * m[11]);
  const double ey = -(m[1] * m[3] + m[5] * m[7] + m[9] * m[11]);
  const double ez = -(m[2] * m[3] + m[6] * m[7] + m[10] * m[11]);
  const double radius = std::sqrt((ex - cx) * (ex - cx) + (ez - cz) * (ez - cz));
  const double start_angle = std::atan2(ex - cx, ez - cz);

  VideoWriter video((fs::path(out) / "render.mp4").string(), int(base.width), int(base.height), 24.0, force);
  double seconds = 0;
  for (int64_t i = 0; i < frames; ++i) {
    model::AvatarPose pose;
    if (poses) {
      pose = train::avatar_pose(*poses, i % poses->size(), device);
    } else {
      const data::SmplxPose p = data::synthetic_pose(kNovelMotionOffset + i, 30.0, t.avatar->config().num_expression_coeffs);
      data::Dataset one;
      one.frames.resize(1);
      one.frames[0].pose = p;
      pose = train::avatar_pose(one, 0, device);
    }
    const double angle = start_angle + kTwoPi * double(i) / double(frames);
    Camera cam = base;
    const double px = cx + radius * std::sin(angle), pz = cz + radius * std::cos(angle);
    // Look at the centre from (px, ey, pz); OpenCV axes with world up +y.
    double fwd[3] = {cx - px, cy - ey, cz - pz};
    const double fn = std::sqrt(fwd[0] * fwd[0] + fwd[1] * fwd[1] + fwd[2] * fwd[2]);
    for (double& v : fwd) v /= fn;
    double right[3] = {-fwd[2], 0.0, fwd[0]};  // fwd x (0, 1, 0)
    const double rn = std::sqrt(right[0] * right[0] + right[2] * right[2]);
    right[0] /= rn;
    right[2] /= rn;
    const double down[3] = {fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2],
                            fwd[0] * right[1] - fwd[1] * right[0]};
    const double eye[3] = {px, ey, pz};
    const double* rows[3] = {right, down, fwd};
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) cam.world_to_camera[size_t(4 * r + c)] = rows[r][c];
      cam.world_to_camera[size_t(4 * r + 3)] = -(rows[r][0] * eye[0] + rows[r][1] * eye[1] + rows[r][2] * eye[2]);
    }
    const auto start = std::chrono::steady_clock::now();
    const model::AvatarOutput o = t.avatar->forward(pose);
    const RenderResult r = render(Gaussians{o.means, {}, {}, o.covariances, o.opacities, o.colours},
                                  at::ones({3}, o.means.options()), cam);
    const at::Tensor image = r.image.cpu();
    seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%04lld.png", (long long)i);
    data::write_png((fs::path(out) / name).string(), image, force);
    video.add(image);
  }
  const bool wrote_video = video.close();
  std::printf("sfgs render: %lld frames to %s (%s); %.1f frames/s (avatar + rasterisation, cached static features)\n",
              (long long)frames, out.c_str(), wrote_video ? "PNG + render.mp4" : "PNG only: no OpenCV video",
              double(frames) / seconds);
  return 0;
}

int run_export(Arguments& args) {
  const train::RunFolder run{args.required("run")};
  const std::string out = args.required("out");
  const int64_t frame = args.integer("frame", -1, -1, INT64_MAX);
  const bool force = args.flag("force");
  args.finish();
  train::TrainedAvatar t = train::load_trained_avatar(run, at::kCPU);
  t.avatar->eval();
  data::Dataset dataset;
  if (frame >= 0) dataset = data::read_dataset(t.dataset);
  train::export_ply(t.avatar, frame >= 0 ? &dataset : nullptr, frame, out, force);
  std::printf("sfgs export: %lld Gaussians (%s) to %s\n", (long long)t.avatar->gaussian_count(),
              frame >= 0 ? ("frame " + std::to_string(frame)).c_str() : "canonical pose", out.c_str());
  return 0;
}

}  // namespace sfgs::cli
