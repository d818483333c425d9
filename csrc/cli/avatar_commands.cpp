// Commands that use a trained avatar: `sfgs eval` and `sfgs render` (views in novel poses, PNG and MP4).
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <algorithm>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "animate/camera_placement.h"
#include "cli/commands.h"
#include "common/math_constants.h"
#include "animate/animator.h"
#include "cli/evaluation_report.h"
#include "cli/frame_encoder.h"
#include "cli/motion_source.h"
#include "cli/video.h"
#include "common/atomic_file.h"
#include "common/folder_lock.h"
#include "data/image_io.h"
#include "train/avatar_keypoints.h"
#include "train/evaluate.h"
#include "train/pose_fit.h"
#include "train/pose_refinement.h"
#include "train/results.h"
#include "train/run_folder.h"
#include "train/constants.h"

namespace sfgs::cli {
namespace fs = std::filesystem;

namespace {

// --device, or else the device the run was trained on where this build has it, else the CPU.
at::Device pick_device(const std::string& name, const train::RunFolder& run) {
  if (name.empty()) {
    std::string trained_on = "cpu";
    try {
      if (fs::exists(run.config_file()))
        trained_on = train::TrainConfig::from_stored_yaml_file(run.config_file()).device;
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

}  // namespace

nlohmann::json evaluation_json(const train::AvatarEvaluation& e) {
  nlohmann::json j{{"frames", e.summary.frames},
                   {"psnr", e.summary.psnr},
                   {"ssim", e.summary.ssim},
                   {"lpips_status", e.summary.lpips_status},
                   {"render_ms", e.render_milliseconds},
                   {"first_render_ms", e.first_render_milliseconds}};
  if (e.summary.lpips) j["lpips"] = *e.summary.lpips;
  if (e.summary.tc_lpips) j["tc_lpips"] = *e.summary.tc_lpips;
  if (e.uncovered_share) j["uncovered_share"] = *e.uncovered_share;
  for (size_t i = 0; i < e.frames.size(); ++i) {
    nlohmann::json f{{"name", e.frame_names[i]}, {"psnr", e.frames[i].psnr}, {"ssim", e.frames[i].ssim}};
    if (e.frames[i].lpips) f["lpips"] = *e.frames[i].lpips;
    j["per_frame"].push_back(f);
  }
  const auto groups = [](const std::vector<train::GroupScore>& scores, bool regions) {
    nlohmann::json list = nlohmann::json::array();
    for (const train::GroupScore& g : scores) {
      // A region no frame showed (enough of) has no score: null, not a PSNR of 0.
      nlohmann::json entry{{"name", g.name}, {"frames", g.frames}, {"psnr", nullptr}, {"ssim", nullptr}};
      if (g.frames > 0) entry["psnr"] = g.psnr, entry["ssim"] = g.ssim;
      if (regions) entry["pixels"] = g.pixels;
      if (regions && g.frames > 0) entry["signed_error"] = g.signed_error;
      if (g.lpips) entry["lpips"] = *g.lpips;
      if (g.unseen_share) entry["unseen_share"] = *g.unseen_share;
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
  if (e.uncovered_share) {
    char line[160];
    std::snprintf(line, sizeof(line), "  person pixels the render leaves uncovered (alpha < %.2f): %.3f %%\n",
                  train::kCoveredAlpha, 100 * *e.uncovered_share);
    text += line;
  }
  char line[256];
  const auto append_unseen = [&](const train::GroupScore& g) {
    if (!g.unseen_share) return;
    std::snprintf(line, sizeof(line), "  unseen %.1f %%", 100 * *g.unseen_share);
    text += line;
  };
  for (const train::GroupScore& g : e.motions) {
    std::snprintf(line, sizeof(line), "  motion %-10s frames %4lld  PSNR %.2f  SSIM %.4f", g.name.c_str(),
                  (long long)g.frames, g.psnr, g.ssim);
    text += line;
    if (g.lpips) {
      std::snprintf(line, sizeof(line), "  LPIPS %.4f", *g.lpips);
      text += line;
    }
    append_unseen(g);
    text += "\n";
  }
  for (const train::GroupScore& g : e.regions) {
    if (g.frames > 0)
      std::snprintf(line, sizeof(line),
                    "  region %-10s frames %4lld  pixels %8.0f  PSNR %.2f  SSIM %.4f  bias %+.3f %+.3f %+.3f",
                    g.name.c_str(), (long long)g.frames, g.pixels, g.psnr, g.ssim, g.signed_error[0], g.signed_error[1],
                    g.signed_error[2]);
    else
      std::snprintf(line, sizeof(line), "  region %-10s frames    0  (no frame showed it)", g.name.c_str());
    text += line;
    append_unseen(g);
    text += "\n";
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
  const bool without_filter = args.flag("no-sampling-filter");
  const bool fit_poses = args.flag("fit-test-poses");
  const bool other_dataset = args.flag("other-dataset");
  train::PoseFitOptions fit;
  fit.iterations = args.integer("fit-iterations", fit.iterations, 1, kMaxIterations);
  fit.keypoint_weight = args.real("fit-keypoint-weight", fit.keypoint_weight, 0, kMaxLossWeight);
  const at::Device device = pick_device(args.text("device", ""), run);
  args.finish();
  const FolderLock lock(run.path, "eval");
  remove_stale_temporaries(run.path);
  // Taken before the checkpoint is read, and again before the result is written: a training that replaces the
  // checkpoint meanwhile cannot leave the old model's metrics beside the new checkpoint.
  train::ResultOrigin origin;
  if (fs::exists(run.checkpoint_file())) origin.checkpoint_crc32 = train::checkpoint_digest(run.checkpoint_file());
  train::TrainedAvatar t = train::load_trained_avatar(run, device);
  if (without_prior) t.avatar->set_observation(at::Tensor());       // every Gaussian trusted (the ablation)
  if (without_filter) t.avatar->set_sampling_record(at::Tensor());  // the splatting alone at any sampling
  const data::Dataset dataset = train::read_run_dataset(t, data_folder, &origin.own_dataset);
  origin.split = split;
  for (const auto& [off, name] :
       {std::pair{without_prior, "no_observation_prior"}, {without_filter, "no_sampling_filter"}})
    if (off) origin.variant += (origin.variant.empty() ? "" : "_") + std::string(name);
  origin.dataset = train::absolute_dataset_path(dataset);
  origin.dataset_fingerprint = dataset.fingerprint();
  origin.checkpoint_iteration = t.iteration;
  origin.command = "sfgs eval " + args.line();
  TORCH_CHECK(origin.own_dataset || other_dataset, "--data '", data_folder, "' is not the dataset run '", run.path,
              "' was trained on (fingerprint ", origin.dataset_fingerprint, ", the run's ", t.dataset_fingerprint,
              "): pass --other-dataset to evaluate it there anyway (written to ", train::metrics_file_name(origin),
              ", apart from the run's own results)");
  t.avatar->eval();
  t.avatar->cache_static_features();
  const auto images = [&](const train::ResultOrigin& o) {
    return save ? (fs::path(run.path) / train::images_folder_name(o)).string() : std::string();
  };
  const train::AvatarEvaluation e = train::evaluate_avatar(dataset, split, t.avatar, options, images(origin), force);
  const std::string written = train::write_result(run, origin, evaluation_json(e));
  std::printf(
      "sfgs eval: %s\n  %s\n  render %.2f ms a frame (median; avatar + rasterisation; the first frame "
      "%.1f ms%s); %s\n%s",
      dataset.source.c_str(), metrics::to_string(e.summary).c_str(), e.render_milliseconds, e.first_render_milliseconds,
      t.avatar->part_labels().is_cuda() ? ", recording the CUDA graph" : "", written.c_str(), group_lines(e).c_str());
  // write_result has just checked that the checkpoint is still the one evaluated: its digest is the current one.
  for (const std::string& stale : train::stale_results(run, origin.checkpoint_crc32))
    std::printf(
        "  note: %s in the run measured another checkpoint than its current one (stale); evaluate again to "
        "replace it\n",
        stale.c_str());
  if (!fit_poses) return 0;
  // The NeuMan protocol's test-time pose fitting, reported beside the plain protocol, never instead of it.
  std::printf("sfgs eval: fitting each frame's pose to its image (%lld loss evaluations, the avatar frozen)\n",
              (long long)fit.iterations);
  fit.loss = t.config.loss;
  const int64_t with_keypoints = dataset.frames_with_keypoints(split);
  const bool anchored = fit.keypoint_weight > 0 && with_keypoints > 0;
  std::printf(
      "  anchored on whole-body keypoints: %s\n",
      anchored
          ? (std::to_string(with_keypoints) + " of " + std::to_string(dataset.split(split).size()) + " frames").c_str()
          : (fit.keypoint_weight > 0 ? "none (no frame of the split has a keypoint file)"
                                     : "no (--fit-keypoint-weight 0)"));
  const std::optional<body::WholeBodyKeypointMap> keypoint_map =
      anchored ? std::optional(train::body_keypoint_map(t.config.body.smplx)) : std::nullopt;
  const data::Dataset fitted =
      train::fit_poses(dataset, split, t.avatar, fit, keypoint_map ? &*keypoint_map : nullptr, true);
  train::ResultOrigin fitted_origin = origin;
  fitted_origin.variant += (fitted_origin.variant.empty() ? "" : "_") + std::string("fitted_poses");
  const train::AvatarEvaluation f =
      train::evaluate_avatar(fitted, split, t.avatar, options, images(fitted_origin), force);
  nlohmann::json fitted_json = evaluation_json(f);
  fitted_json["pose_fitting"] = {{"iterations", fit.iterations},
                                 {"keypoint_weight", anchored ? fit.keypoint_weight : 0.0},
                                 {"frames_with_keypoints", anchored ? with_keypoints : 0}};
  const std::string fitted_written = train::write_result(run, fitted_origin, fitted_json);
  std::printf("sfgs eval with fitted poses: %s\n  %s\n  %s\n%s", dataset.source.c_str(),
              metrics::to_string(f.summary).c_str(), fitted_written.c_str(), group_lines(f).c_str());
  return 0;
}

namespace {

// The files a render has written so far: removed again if it fails, so a failed render leaves nothing half done.
class WrittenFiles {
 public:
  void add(const std::string& path) { paths_.push_back(path); }
  size_t size() const { return paths_.size(); }
  const std::vector<std::string>& paths() const { return paths_; }
  void remove_all() {
    for (const std::string& p : paths_) std::remove(p.c_str());
    paths_.clear();
  }

 private:
  std::vector<std::string> paths_;
};

// What a render keeps beside its frames: the list of files it wrote, so that a later --force replaces exactly those.
constexpr const char* kRenderManifest = "render.json";
constexpr const char* kRenderManifestFormat = "sfgs-render";

// The files an earlier render left in `folder` (from its manifest; before renders kept one, the frames and video by
// their names), checked before anything is written: a folder holding an earlier render needs --force, and any other
// file (one the user put there) is an error naming it, --force or not. Lock files and temporaries do not count.
std::vector<std::string> earlier_render_files(const std::string& folder, bool force) {
  std::vector<std::string> earlier;
  if (!fs::is_directory(folder)) return earlier;
  std::set<std::string> listed;
  const fs::path manifest = fs::path(folder) / kRenderManifest;
  if (fs::exists(manifest)) {
    nlohmann::json j;
    try {
      std::ifstream in(manifest);
      j = nlohmann::json::parse(in);
    } catch (const std::exception&) {
    }
    TORCH_CHECK(j.is_object() && j.value("format", "") == kRenderManifestFormat && j.contains("written"), "render: '",
                manifest.string(), "' is not a manifest sfgs wrote: render into another folder");
    for (const auto& name : j.at("written")) listed.insert(name.get<std::string>());
  }
  static const std::regex own_name(R"(frame_[0-9]{4,}\.png|render\.mp4)");
  static const std::regex not_counted(R"(\.sfgs-.*\.lock|.+\.tmp-[0-9]+.*)");
  std::vector<std::string> foreign;
  for (const fs::directory_entry& e : fs::directory_iterator(folder)) {
    const std::string name = e.path().filename().string();
    if (std::regex_match(name, not_counted)) continue;
    if (name == kRenderManifest || listed.count(name) || (listed.empty() && std::regex_match(name, own_name)))
      earlier.push_back(name);
    else
      foreign.push_back(name);
  }
  std::sort(foreign.begin(), foreign.end());
  TORCH_CHECK(foreign.empty(), "render: '", folder, "' holds '", foreign.front(), "'",
              foreign.size() > 1 ? " and " + std::to_string(foreign.size() - 1) + " more file(s)" : std::string(),
              " that no sfgs render wrote: render into another folder (nothing there was changed)");
  TORCH_CHECK(earlier.empty() || force, "render: '", folder, "' holds an earlier render (", earlier.size(),
              " files): pass --force to replace it");
  return earlier;
}

struct RenderRequest {
  std::string out, motion, data;
  int64_t frames = 0;  // 0: the whole motion file, or kDefaultRenderFrames of another motion
  bool force = false;
  std::string camera;  // orbit, fixed or follow; empty: the dataset's camera orbiting (library and dataset motions)
  double distance = animate::kFramingDistance, height = 0, fps = kRenderFramesPerSecond;
  int64_t width = 0, image_height = 0;  // 0: the training dataset's
};

struct RenderPace {
  // Avatar + rasterisation + the 8-bit image's copy to the host: the median frame and the first (which on CUDA also
  // records the graph).
  double median_frame_ms = 0, first_frame_ms = 0;
  double encode_fps = 0;  // PNG + MP4 encoding, on background threads beside the render
  double total_seconds = 0;
  int encode_threads = 0;
};

// Renders the frames into PNGs and the video: the Animator renders (on CUDA one graph replay a frame, whatever the
// camera), background threads encode.
RenderPace render_frames(train::TrainedAvatar& t, RenderRequest& request, WrittenFiles& written, bool& wrote_video) {
  const data::Dataset trained_on = train::read_run_dataset(t, request.data);
  const MotionSource source(request.motion, request.fps, request.frames, trained_on);
  if (!source.note().empty()) std::printf("sfgs render: %s: %s\n", request.motion.c_str(), source.note().c_str());
  request.frames = source.frame_count();
  // A motion file may walk anywhere: the camera follows it. A size of one's own needs a camera of one's own.
  if (request.camera.empty() && source.is_file()) request.camera = "follow";
  if (request.camera.empty() && request.width > 0) request.camera = "orbit";
  t.avatar->eval();
  t.avatar->cache_static_features();
  at::NoGradGuard no_grad;
  const Camera base = train::render_camera(trained_on.frames[0]);
  const int64_t width = request.width > 0 ? request.width : base.width;
  const int64_t height = request.image_height > 0 ? request.image_height : base.height;
  const Camera lens = Camera::looking_forward(animate::kFramingFocalPerHeight * double(height), width, height);
  // The dataset's camera orbits the training frame's body; the other cameras aim at the motion's first frame (orbit,
  // fixed) or follow the body's root as it moves (follow), from the front (+Z, where the body model faces).
  const body::SmplxPose first_pose = source.pose(t.avatar, 0);
  const std::array<double, 3> first = request.camera.empty()
                                          ? animate::centre_of(train::pose_avatar(t.avatar, trained_on, 0))
                                          : animate::centre_of(t.avatar->forward(first_pose, source.replay_time(0)));
  const auto root_of = [](const body::SmplxPose& pose) {
    std::array<double, 3> root{0, 0, 0};
    if (!pose.transl.defined()) return root;
    const at::Tensor transl = pose.transl.detach().reshape({-1}).to(at::kCPU, at::kDouble);
    for (int k = 0; k < 3; ++k) root[size_t(k)] = transl[k].item<double>();
    return root;
  };
  const std::array<double, 3> first_root = root_of(first_pose);
  const auto camera_at = [&](int64_t i, const body::SmplxPose& pose) {
    const double angle = kTwoPi * double(i) / double(request.frames);
    if (request.camera.empty()) return animate::orbit_camera(base, first, angle);
    std::array<double, 3> target = first;
    if (request.camera == "follow") {
      const std::array<double, 3> root = root_of(pose);
      for (size_t k = 0; k < 3; ++k) target[k] += root[k] - first_root[k];
    }
    return animate::camera_in_front(lens, target, request.distance, request.height,
                                    request.camera == "orbit" ? angle : 0.0);
  };
  VideoWriter video((fs::path(request.out) / "render.mp4").string(), int(width), int(height), request.fps,
                    request.force);
  RenderPace pace;
  pace.encode_threads = std::max(1, int(std::thread::hardware_concurrency()) - 1);
  const auto started = std::chrono::steady_clock::now();
  std::vector<double> frame_ms;
  {
    FrameEncoder encoder(video.available() ? &video : nullptr, request.force, pace.encode_threads);
    animate::Animator animator(t.avatar, camera_at(0, first_pose), at::ones({3}));
    for (int64_t i = 0; i < request.frames; ++i) {
      const body::SmplxPose pose = i == 0 ? first_pose : source.pose(t.avatar, i);
      animator.set_camera(camera_at(i, pose));
      const auto start = std::chrono::steady_clock::now();
      const at::Tensor image = eight_bit_image(animator.render(pose, source.replay_time(i)));
      frame_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
      char name[32];
      std::snprintf(name, sizeof(name), "frame_%04lld.png", (long long)i);
      const std::string path = (fs::path(request.out) / name).string();
      written.add(path);
      encoder.add(path, image);
    }
    encoder.finish();
    // Encoding overlaps the render: its pace is the frames over the time until the last one was written.
    pace.encode_fps = double(request.frames) /
                      std::max(std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count(), 1e-9);
  }
  wrote_video = video.close();
  pace.first_frame_ms = frame_ms.front();
  std::nth_element(frame_ms.begin(), frame_ms.begin() + ptrdiff_t(frame_ms.size() / 2), frame_ms.end());
  pace.median_frame_ms = frame_ms[frame_ms.size() / 2];
  pace.total_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  return pace;
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
  TORCH_CHECK(
      request.camera.empty() || request.camera == "orbit" || request.camera == "fixed" || request.camera == "follow",
      "render: --camera must be orbit, fixed or follow, got '", request.camera, "'");
  request.distance = args.real("distance", animate::kFramingDistance, 1e-3, 1e4);
  request.height = args.real("height", 0.0, -1e4, 1e4);
  request.fps = args.real("fps", kRenderFramesPerSecond, 1.0, 1000.0);
  const std::array<int64_t, 2> size = args.image_size("size");
  request.width = size[0];
  request.image_height = size[1];
  const at::Device device = pick_device(args.text("device", ""), run);
  args.finish();
  train::TrainedAvatar t = train::load_trained_avatar(run, device);
  const FolderLock lock(request.out, "render");
  remove_stale_temporaries(request.out);
  const std::vector<std::string> earlier = earlier_render_files(request.out, request.force);
  WrittenFiles written;
  bool wrote_video = false;
  RenderPace pace;
  const auto stopped = [&](const std::string& what) {
    const size_t frames = written.size();
    written.remove_all();
    return std::runtime_error(what + "\n  the render stopped after " + std::to_string(frames) + " of " +
                              std::to_string(request.frames) + " frames; the " + std::to_string(frames) +
                              " frames it had written to '" + request.out + "' were removed");
  };
  try {
    pace = render_frames(t, request, written, wrote_video);
  } catch (const c10::Error& e) {
    throw stopped(e.what_without_backtrace());
  } catch (const std::exception& e) {
    throw stopped(e.what());
  }
  // The manifest lists what this render wrote; what the earlier one wrote beyond that goes (its extra frames).
  std::set<std::string> names;
  for (const std::string& path : written.paths()) names.insert(fs::path(path).filename().string());
  if (wrote_video) names.insert("render.mp4");
  const nlohmann::json manifest = {{"format", kRenderManifestFormat},
                                   {"run", run.path},
                                   {"motion", request.motion},
                                   {"frames", request.frames},
                                   {"command", "sfgs render " + args.line()},
                                   {"written", names}};
  const std::string text = manifest.dump(1) + "\n";
  write_file_atomically((fs::path(request.out) / kRenderManifest).string(),
                        std::vector<unsigned char>(text.begin(), text.end()), true);
  for (const std::string& name : earlier)
    if (name != kRenderManifest && !names.count(name)) fs::remove(fs::path(request.out) / name);
  std::printf(
      "sfgs render: %lld frames to %s (%s) in %.2f s\n"
      "  render %.1f frames/s (median frame %.2f ms: avatar + rasterisation%s; the first frame %.1f ms)\n"
      "  encode %.1f frames/s (%d PNG threads%s, beside the render)\n",
      (long long)request.frames, request.out.c_str(),
      wrote_video ? "PNG + render.mp4" : "PNG only: this build's OpenCV has no MP4 encoder", pace.total_seconds,
      1e3 / std::max(pace.median_frame_ms, 1e-9), pace.median_frame_ms, device.is_cuda() ? ", a CUDA graph replay" : "",
      pace.first_frame_ms, pace.encode_fps, pace.encode_threads, wrote_video ? " and one for the video" : "");
  return 0;
}

}  // namespace sfgs::cli
