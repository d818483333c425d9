// Commands that use a trained avatar: `sfgs eval`, `sfgs render` (orbit views in novel poses, PNG and MP4) and
// `sfgs export` (.ply).
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <stdexcept>
#include <vector>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "cli/commands.h"
#include "cli/evaluation_report.h"
#include "cli/video.h"
#include "common/atomic_file.h"
#include "common/folder_lock.h"
#include "data/image_io.h"
#include "data/motion_file.h"
#include "data/motions.h"
#include "train/evaluate.h"
#include "train/export.h"
#include "train/run_folder.h"

namespace sfgs::cli {
namespace fs = std::filesystem;

namespace {

constexpr double kTwoPi = 6.283185307179586;
// Cameras of `render --camera orbit|fixed|follow`: distance from the body's centre (m), focal length as a multiple
// of the image height (about 45 degrees of vertical view).
constexpr double kRenderCameraDistance = 2.8;
constexpr double kRenderFocalPerHeight = 1.2;
constexpr double kRenderFramesPerSecond = 24.0;  // of the video, and of library motions sampled for it

// --device, or else the device the run was trained on where this build has it, else the CPU.
at::Device pick_device(const std::string& name, const train::RunFolder& run) {
  if (name.empty()) {
    std::string trained_on = "cpu";
    try {
      if (fs::exists(run.config_file())) trained_on = train::TrainConfig::from_yaml_file(run.config_file()).device;
    } catch (const c10::Error&) {
      // An unreadable config.yaml only loses the hint; the checkpoint holds the config that counts.
    }
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
  const auto groups = [](const std::vector<train::GroupScore>& scores, bool regions) {
    nlohmann::json list = nlohmann::json::array();
    for (const train::GroupScore& g : scores) {
      nlohmann::json entry{{"name", g.name}, {"frames", g.frames}, {"psnr", g.psnr}, {"ssim", g.ssim}};
      if (regions) entry["pixels"] = g.pixels;
      if (g.lpips) entry["lpips"] = *g.lpips;
      list.push_back(entry);
    }
    return list;
  };
  j["motions"] = groups(e.motions, false);
  j["regions"] = groups(e.regions, true);
  return j;
}

std::string group_lines(const train::AvatarEvaluation& e) {
  std::string text;
  char line[256];
  for (const train::GroupScore& g : e.motions) {
    std::snprintf(line, sizeof(line), "  motion %-10s frames %4lld  PSNR %.2f  SSIM %.4f", g.name.c_str(),
                  (long long)g.frames, g.psnr, g.ssim);
    text += line;
    if (g.lpips) {
      std::snprintf(line, sizeof(line), "  LPIPS %.4f", *g.lpips);
      text += line;
    }
    text += "\n";
  }
  for (const train::GroupScore& g : e.regions) {
    std::snprintf(line, sizeof(line), "  region %-10s frames %4lld  pixels %8.0f  PSNR %.2f  SSIM %.4f\n",
                  g.name.c_str(), (long long)g.frames, g.pixels, g.psnr, g.ssim);
    text += line;
  }
  if (e.regions.empty()) text += "  (no per-region metrics: the dataset has no ground-truth geometry)\n";
  return text;
}

int run_eval(Arguments& args) {
  const train::RunFolder run{args.required("run")};
  const std::string data_folder = args.text("data", "");
  const data::Split split = parse_split(args.text("split", "test"));
  metrics::EvaluationOptions options;
  options.eight_bit_round_trip = args.flag("eight-bit");
  const bool save = args.flag("save-images");
  const bool force = args.flag("force");
  const bool without_prior = args.flag("no-observation-prior");
  const at::Device device = pick_device(args.text("device", ""), run);
  args.finish();
  const FolderLock lock(run.path, "eval");
  remove_stale_temporaries(run.path);
  train::TrainedAvatar t = train::load_trained_avatar(run, device);
  if (without_prior) t.avatar->set_observation(at::Tensor());  // every Gaussian trusted (the ablation)
  const data::Dataset dataset = train::read_run_dataset(t, data_folder);
  t.avatar->eval();
  t.avatar->cache_static_features();
  const train::AvatarEvaluation e = train::evaluate_avatar(
      dataset, split, t.avatar, options, save ? (fs::path(run.path) / "eval_images").string() : "", force);
  write_text_atomically((fs::path(run.path) / "metrics.json").string(), evaluation_json(e).dump(1) + "\n");
  std::printf("sfgs eval: %s\n  %s\n  render %.2f ms per frame (avatar + rasterisation); metrics.json in %s\n%s",
              dataset.source.c_str(), metrics::to_string(e.summary).c_str(), e.render_milliseconds, run.path.c_str(),
              group_lines(e).c_str());
  return 0;
}

namespace {

// `lens` (its intrinsics and size) placed at `eye` and looking at `target`, world +Y up (the body model's frame),
// image x to the world's right (OpenCV axes).
Camera look_at_camera(const Camera& lens, const std::array<double, 3>& eye, const std::array<double, 3>& target) {
  double fwd[3] = {target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]};
  const double fn = std::sqrt(fwd[0] * fwd[0] + fwd[1] * fwd[1] + fwd[2] * fwd[2]);
  TORCH_CHECK(fn > 0, "render: the camera distance must be positive");
  for (double& v : fwd) v /= fn;
  double right[3] = {-fwd[2], 0.0, fwd[0]};  // fwd x (0, 1, 0)
  const double rn = std::sqrt(right[0] * right[0] + right[2] * right[2]);
  TORCH_CHECK(rn > 0, "render: the camera looks straight up or down (its height is its whole distance)");
  right[0] /= rn;
  right[2] /= rn;
  const double down[3] = {fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2],
                          fwd[0] * right[1] - fwd[1] * right[0]};
  const double* rows[3] = {right, down, fwd};
  Camera cam = lens;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam.world_to_camera[size_t(4 * r + c)] = rows[r][c];
    cam.world_to_camera[size_t(4 * r + 3)] = -(rows[r][0] * eye[0] + rows[r][1] * eye[1] + rows[r][2] * eye[2]);
  }
  return cam;
}

// The camera circling the subject: at the distance and height of `base`'s centre around `centre`, `angle` radians
// on from base's own position, looking at the centre.
Camera orbit_camera(const Camera& base, const std::array<double, 3>& centre, double angle) {
  const std::array<double, 3> e = camera_centre(base);
  const double radius = std::hypot(e[0] - centre[0], e[2] - centre[2]);
  const double a = std::atan2(e[0] - centre[0], e[2] - centre[2]) + angle;
  return look_at_camera(base, {centre[0] + radius * std::sin(a), e[1], centre[2] + radius * std::cos(a)}, centre);
}

// The files a render has written so far: removed again if it fails, so a failed render leaves nothing half done.
class WrittenFiles {
 public:
  void add(const std::string& path) { paths_.push_back(path); }
  size_t size() const { return paths_.size(); }
  void remove_all() {
    for (const std::string& p : paths_) std::remove(p.c_str());
    paths_.clear();
  }

 private:
  std::vector<std::string> paths_;
};

struct RenderRequest {
  std::string out, motion, data;
  int64_t frames = 0;  // 0: the whole motion file, or kDefaultRenderFrames of another motion
  bool force = false;
  std::string camera;  // orbit, fixed or follow; empty: the dataset's camera orbiting (library and dataset motions)
  double distance = kRenderCameraDistance, height = 0, fps = kRenderFramesPerSecond;
  int64_t width = 0, image_height = 0;  // 0: the training dataset's
};

constexpr int64_t kDefaultRenderFrames = 48;

// The centre of the posed body's bounding box (the mean of the Gaussians sits high: hands and face are dense).
std::array<double, 3> centre_of(const model::AvatarOutput& o) {
  const at::Tensor points = o.means.detach();
  const at::Tensor c = ((std::get<0>(points.min(0)) + std::get<0>(points.max(0))) / 2).cpu().to(at::kDouble);
  return {c[0].item<double>(), c[1].item<double>(), c[2].item<double>()};
}

// Renders the frames into PNGs and the video; returns the frames per second of avatar + rasterisation.
double render_frames(train::TrainedAvatar& t, RenderRequest& request, WrittenFiles& written, bool& wrote_video) {
  const data::Dataset trained_on = train::read_run_dataset(t, request.data);
  std::optional<data::Dataset> motion;
  std::optional<data::MotionClip> clip;
  if (data::is_motion_file(request.motion)) {
    clip = data::resample(data::read_motion(request.motion), request.fps);
    if (!clip->note.empty()) std::printf("sfgs render: %s: %s\n", request.motion.c_str(), clip->note.c_str());
    const int64_t length = static_cast<int64_t>(clip->poses.size());
    request.frames = request.frames > 0 ? std::min(request.frames, length) : length;
  } else if (!data::is_motion(request.motion)) {
    motion = data::read_dataset(request.motion);
  }
  if (request.frames == 0) request.frames = kDefaultRenderFrames;
  // A motion file may walk anywhere: the camera follows it. A size of one's own needs a camera of one's own.
  if (request.camera.empty() && clip) request.camera = "follow";
  if (request.camera.empty() && request.width > 0) request.camera = "orbit";
  // A motion from another dataset is new to the avatar: no time (model/frame_time.h). Frames of the training
  // dataset keep their replay times.
  const bool replay = motion && motion->fingerprint() == trained_on.fingerprint();
  t.avatar->eval();
  t.avatar->cache_static_features();
  at::NoGradGuard no_grad;
  const auto pose_at = [&](int64_t i) {
    if (clip) return t.avatar->forward(train::clip_pose(t.avatar, *clip, i), std::nullopt);
    if (replay) return train::pose_avatar(t.avatar, *motion, i % motion->size());
    if (motion) return t.avatar->forward(motion->frames[size_t(i % motion->size())].pose, std::nullopt);
    return t.avatar->forward(data::motion_pose(request.motion, double(i) / request.fps,
                                               t.avatar->config().num_expression_coeffs),
                             std::nullopt);
  };
  const Camera base = train::render_camera(trained_on.frames[0]);
  const int64_t width = request.width > 0 ? request.width : base.width;
  const int64_t height = request.image_height > 0 ? request.image_height : base.height;
  const Camera lens = Camera::looking_forward(kRenderFocalPerHeight * double(height), width, height);
  // The dataset's camera orbits the training frame's body; the other cameras aim at the motion's first frame (orbit,
  // fixed) or at every frame's body (follow), from the front (+Z, where the body model faces).
  const std::array<double, 3> first = request.camera.empty() ? centre_of(train::pose_avatar(t.avatar, trained_on, 0))
                                                             : centre_of(pose_at(0));
  const auto camera_at = [&](int64_t i, const model::AvatarOutput& o) {
    const double angle = kTwoPi * double(i) / double(request.frames);
    if (request.camera.empty()) return orbit_camera(base, first, angle);
    const std::array<double, 3> target = request.camera == "follow" ? centre_of(o) : first;
    const double a = request.camera == "orbit" ? angle : 0.0;
    const std::array<double, 3> eye{target[0] + request.distance * std::sin(a), target[1] + request.height,
                                    target[2] + request.distance * std::cos(a)};
    return look_at_camera(lens, eye, target);
  };
  VideoWriter video((fs::path(request.out) / "render.mp4").string(), int(width), int(height), request.fps,
                    request.force);
  double seconds = 0;
  for (int64_t i = 0; i < request.frames; ++i) {
    const auto start = std::chrono::steady_clock::now();
    const model::AvatarOutput o = pose_at(i);
    const Camera cam = camera_at(i, o);
    const at::Tensor image = render(model::to_gaussians(o), at::ones({3}, o.means.options()), cam).image.cpu();
    seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%04lld.png", (long long)i);
    const std::string path = (fs::path(request.out) / name).string();
    data::write_png(path, image, request.force);
    written.add(path);
    video.add(image);
  }
  wrote_video = video.close();
  return double(request.frames) / seconds;
}

}  // namespace

int run_render(Arguments& args) {
  const train::RunFolder run{args.required("run")};
  RenderRequest request;
  request.out = args.required("out");
  request.frames = args.has("frames") ? args.integer("frames", kDefaultRenderFrames, 1, 100000) : 0;
  request.motion = args.text("motion", "overhead");
  request.data = args.text("data", "");
  request.force = args.flag("force");
  request.camera = args.text("camera", "");
  TORCH_CHECK(request.camera.empty() || request.camera == "orbit" || request.camera == "fixed" ||
                  request.camera == "follow",
              "render: --camera must be orbit, fixed or follow, got '", request.camera, "'");
  request.distance = args.real("distance", kRenderCameraDistance, 1e-3, 1e4);
  request.height = args.real("height", 0.0, -1e4, 1e4);
  request.fps = args.real("fps", kRenderFramesPerSecond, 1.0, 1000.0);
  if (args.has("size")) {
    const std::string size = args.text("size", "");
    long w = 0, h = 0;
    char rest = 0;
    TORCH_CHECK(std::sscanf(size.c_str(), "%ldx%ld%c", &w, &h, &rest) == 2 && w > 0 && h > 0 && w <= 16384 &&
                    h <= 16384,
                "render: --size must be WIDTHxHEIGHT (for example 540x960), got '", size, "'");
    request.width = w;
    request.image_height = h;
  }
  const at::Device device = pick_device(args.text("device", ""), run);
  args.finish();
  train::TrainedAvatar t = train::load_trained_avatar(run, device);
  const FolderLock lock(request.out, "render");
  remove_stale_temporaries(request.out);
  WrittenFiles written;
  bool wrote_video = false;
  double fps = 0;
  try {
    fps = render_frames(t, request, written, wrote_video);
  } catch (const std::exception& e) {
    const size_t frames = written.size();
    written.remove_all();
    throw std::runtime_error(std::string(e.what()) + "\n  the render stopped after " + std::to_string(frames) + " of " +
                             std::to_string(request.frames) + " frames; the " + std::to_string(frames) +
                             " frames it had written to '" + request.out + "' were removed");
  }
  std::printf("sfgs render: %lld frames to %s (%s); %.1f frames/s (avatar + rasterisation, cached static features)\n",
              (long long)request.frames, request.out.c_str(),
              wrote_video ? "PNG + render.mp4" : "PNG only: this build's OpenCV has no MP4 encoder", fps);
  return 0;
}

int run_export(Arguments& args) {
  const train::RunFolder run{args.required("run")};
  const std::string out = args.required("out");
  const int64_t frame = args.integer("frame", -1, -1, INT64_MAX);
  const std::string data_folder = args.text("data", "");
  const bool force = args.flag("force");
  args.finish();
  train::TrainedAvatar t = train::load_trained_avatar(run, at::kCPU);
  t.avatar->eval();
  std::optional<data::Dataset> dataset;
  if (frame >= 0) dataset = train::read_run_dataset(t, data_folder);
  const fs::path folder = fs::path(out).has_parent_path() ? fs::path(out).parent_path() : fs::path(".");
  remove_stale_temporaries(folder.string());
  train::export_gaussians(t.avatar, dataset ? &*dataset : nullptr, frame, out, force);
  std::printf("sfgs export: %lld Gaussians (%s) to %s\n", (long long)t.avatar->gaussian_count(),
              frame >= 0 ? ("frame " + std::to_string(frame)).c_str() : "canonical pose", out.c_str());
  return 0;
}

}  // namespace sfgs::cli
