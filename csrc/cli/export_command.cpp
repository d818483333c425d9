// `sfgs export`: the avatar's Gaussians for other viewers (.ply, .splat, one pose), or the animated avatar as a
// folder that plays in a web browser (--web).
#include <array>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>

#include <ATen/ATen.h>

#include "animate/camera_placement.h"
#include "cli/commands.h"
#include "cli/motion_source.h"
#include "common/atomic_file.h"
#include "train/export.h"
#include "train/run_folder.h"
#include "train/web_export.h"

namespace sfgs::cli {
namespace fs = std::filesystem;

namespace {

// One pose of the Gaussians as a .ply or .splat file.
int export_file(Arguments& args, const train::RunFolder& run, const std::string& out) {
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

// The web viewer's folder: the motion read as `sfgs render --motion` reads it, every frame posed as a new motion,
// and the still camera of `sfgs render --camera fixed` with the same size, distance and height.
int export_web(Arguments& args, const train::RunFolder& run, const std::string& folder) {
  const std::string motion = args.text("motion", "overhead");
  const int64_t frames = args.has("frames") ? args.integer("frames", kDefaultRenderFrames, 1, 100000) : 0;
  const double fps = args.real("fps", kRenderFramesPerSecond, 1.0, 1000.0);
  const std::array<int64_t, 2> size = args.image_size("size");
  const double distance = args.real("distance", animate::kFramingDistance, 1e-3, 1e4);
  const double height = args.real("height", 0.0, -1e4, 1e4);
  const std::string data_folder = args.text("data", "");
  const bool force = args.flag("force");
  args.finish();
  train::check_web_folder(folder, force);
  train::TrainedAvatar t = train::load_trained_avatar(run, at::kCPU);
  const data::Dataset trained_on = train::read_run_dataset(t, data_folder);
  const MotionSource source(motion, fps, frames, trained_on);
  if (!source.note().empty()) std::printf("sfgs export: %s: %s\n", motion.c_str(), source.note().c_str());
  t.avatar->eval();
  t.avatar->cache_static_features();
  at::NoGradGuard no_grad;
  train::WebMotion web_motion;
  web_motion.name = motion;
  web_motion.frames = source.frame_count();
  web_motion.frames_per_second = fps;
  web_motion.pose = [&](int64_t i) { return t.avatar->forward(source.pose(t.avatar, i), std::nullopt); };
  const Camera base = train::render_camera(trained_on.frames[0]);
  const int64_t width = size[0] > 0 ? size[0] : base.width, image_height = size[1] > 0 ? size[1] : base.height;
  const Camera lens =
      Camera::looking_forward(animate::kFramingFocalPerHeight * double(image_height), width, image_height);
  train::WebCamera camera;
  camera.target = animate::centre_of(web_motion.pose(0));
  camera.camera = animate::camera_in_front(lens, camera.target, distance, height, 0.0);
  const train::WebExportSummary s = train::export_web_viewer(t.avatar, web_motion, camera, folder, force);
  std::printf(
      "sfgs export: %s playing '%s' to %s: %lld Gaussians (skinned by their %lld strongest joints), %lld frames at "
      "%g frames/s; data %.1f MB shared + %.2f MB a frame, folder %.1f MB; posed means within %.1f mm of the "
      "skinned rest pose. Open %s/index.html in a browser with WebGL2.\n",
      run.path.c_str(), motion.c_str(), folder.c_str(), (long long)s.gaussians, (long long)s.influences,
      (long long)s.frames, fps, double(s.static_bytes) / 1e6, double(s.frame_bytes) / 1e6, double(s.folder_bytes) / 1e6,
      s.largest_offset * 1e3, folder.c_str());
  if (!s.note.empty()) std::printf("sfgs export: note: %s\n", s.note.c_str());
  return 0;
}

}  // namespace

int run_export(Arguments& args) {
  const train::RunFolder run{args.required("run")};
  TORCH_CHECK(args.has("out") != args.has("web"), "give either --out FILE.ply|FILE.splat (one pose) or --web FOLDER ",
              "(the animated avatar for web browsers)");
  if (args.has("web")) return export_web(args, run, args.text("web", ""));
  return export_file(args, run, args.required("out"));
}

}  // namespace sfgs::cli
