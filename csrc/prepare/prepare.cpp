#include "prepare/prepare.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <exception>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "common/background_jobs.h"
#include "data/image_io.h"
#include "data/keypoint_file.h"
#include "data/neuman_writer.h"
#include "data/synthetic_layouts.h"
#include "detect/wholebody.h"
#include "prepare/video_metadata.h"
#include "train/progress.h"

namespace sfgs::prepare {
namespace fs = std::filesystem;
namespace {

// A mask pixel is the person where the segmentation's probability exceeds this.
constexpr double kMaskThreshold = 0.5;
constexpr int64_t kProgressEvery = 30;  // frames between progress lines
// Frames decoded ahead of detection, and threads encoding and writing each frame's files beside it (at most; one per
// core) with twice as many frames' files queued: decoding and PNG encoding took as long as detection on a GPU.
constexpr size_t kFramesReadAhead = 4;
constexpr int kMaxWriterThreads = 4;

}  // namespace

FrameSource image_folder(const std::string& folder) {
  TORCH_CHECK(fs::is_directory(folder), "prepare: '", folder, "' is neither a video nor a folder of images");
  std::vector<std::string> files;
  for (const auto& entry : fs::directory_iterator(folder)) {
    std::string extension = entry.path().extension().string();
    std::transform(extension.begin(), extension.end(), extension.begin(), ::tolower);
    if (entry.is_regular_file() && (extension == ".png" || extension == ".jpg" || extension == ".jpeg"))
      files.push_back(entry.path().string());
  }
  std::sort(files.begin(), files.end());
  TORCH_CHECK(!files.empty(), "prepare: folder '", folder, "' holds no .png or .jpg images");
  auto next = std::make_shared<size_t>(0);
  return [files, next]() -> std::optional<at::Tensor> {
    if (*next >= files.size()) return std::nullopt;
    return data::read_image_rgb(files[(*next)++]);
  };
}

FrameSource read_ahead(FrameSource source, size_t depth) {
  struct Reader {
    std::mutex mutex;
    std::condition_variable changed;
    std::deque<std::optional<at::Tensor>> ready;
    std::exception_ptr error;
    bool ended = false, stopping = false;
    std::thread thread;
    ~Reader() {
      {
        const std::lock_guard<std::mutex> lock(mutex);
        stopping = true;
      }
      changed.notify_all();
      if (thread.joinable()) thread.join();
    }
  };
  auto reader = std::make_shared<Reader>();
  const size_t capacity = std::max<size_t>(depth, 1);
  reader->thread = std::thread([r = reader.get(), source = std::move(source), capacity] {
    for (;;) {
      {
        std::unique_lock<std::mutex> lock(r->mutex);
        r->changed.wait(lock, [&] { return r->stopping || r->ready.size() < capacity; });
        if (r->stopping) return;
      }
      std::optional<at::Tensor> frame;
      std::exception_ptr error;
      try {
        frame = source();
      } catch (...) {
        error = std::current_exception();
      }
      {
        const std::lock_guard<std::mutex> lock(r->mutex);
        if (error)
          r->error = error;
        else
          r->ready.push_back(frame);
        if (error || !frame) r->ended = true;
      }
      r->changed.notify_all();
      if (error || !frame) return;
    }
  });
  return [reader]() -> std::optional<at::Tensor> {
    std::unique_lock<std::mutex> lock(reader->mutex);
    reader->changed.wait(lock, [&] { return !reader->ready.empty() || reader->ended; });
    if (reader->ready.empty()) {
      if (reader->error) std::rethrow_exception(reader->error);
      return std::nullopt;
    }
    std::optional<at::Tensor> frame = std::move(reader->ready.front());
    reader->ready.pop_front();
    lock.unlock();
    reader->changed.notify_all();
    return frame;
  };
}

PrepareReport prepare_dataset(const FrameSource& frames, const PrepareOptions& options) {
  TORCH_CHECK(!options.out.empty(), "prepare: give the dataset folder (--out)");
  TORCH_CHECK(options.device == "cpu" || options.device == "cuda", "prepare: device must be cpu or cuda, got '",
              options.device, "'");
  TORCH_CHECK(options.frames_per_second > 0 && std::isfinite(options.frames_per_second),
              "prepare: the frame rate must be positive, got ", options.frames_per_second);
  const fs::path out = fs::absolute(options.out);
  TORCH_CHECK(options.overwrite || !fs::exists(out) || fs::is_empty(out), "prepare: '", out.string(),
              "' exists; give another folder or --force to replace it");
  if (out.has_parent_path()) fs::create_directories(out.parent_path());
  const fs::path building = temporary_path(out.string());
  remove_tree(building.string());
  // Removes the folder being built unless it was moved into place: an error leaves nothing behind.
  struct Unfinished {
    fs::path folder;
    ~Unfinished() { remove_tree(folder.string()); }
  } unfinished{building};
  fs::create_directories(building / "images");
  fs::create_directories(building / "masks");
  fs::create_directories(building / "keypoints_whole_body");
  train::JsonLinesLog log((building / "prepare_log.jsonl").string());

  const at::Device device = options.device == "cuda" ? at::Device(at::kCUDA) : at::Device(at::kCPU);
  detect::PoseOptions pose_options;
  pose_options.model = options.model;
  pose_options.smooth = options.smooth;
  detect::PoseTracker tracker(device, pose_options);
  const detect::PartsLandmarker parts(device);
  PrepareReport report;
  std::vector<data::ColmapFrame> cameras;
  std::map<data::Split, std::vector<std::string>> splits;
  Camera camera;  // every frame's: at the origin, with the focal length given, the video's or the default
  const FrameSource next_frame = read_ahead(frames, kFramesReadAhead);
  const int writers = std::clamp(int(std::thread::hardware_concurrency()), 1, kMaxWriterThreads);
  BackgroundJobs files(writers, 2 * size_t(writers));
  const auto started = std::chrono::steady_clock::now();
  while (options.max_frames <= 0 || report.frames < options.max_frames) {
    const std::optional<at::Tensor> next = next_frame();
    if (!next) break;
    const at::Tensor& image = *next;
    TORCH_CHECK(image.dim() == 3 && image.size(2) == 3, "prepare: frame ", report.frames, " is not an RGB image");
    if (report.frames == 0) {
      report.height = image.size(0);
      report.width = image.size(1);
      if (options.focal > 0) {
        report.focal = options.focal;
        report.focal_source = "given";
      } else if (options.focal_35mm > 0) {
        report.focal = focal_pixels_from_35mm(options.focal_35mm, report.width, report.height);
        report.focal_source = "metadata";
      } else {
        report.focal = double(std::max(report.width, report.height));
        report.focal_source = "default";
      }
      camera = Camera::looking_forward(report.focal, report.width, report.height);
    }
    TORCH_CHECK(image.size(0) == report.height && image.size(1) == report.width, "prepare: frame ", report.frames,
                " is ", image.size(1), " x ", image.size(0), ", the first was ", report.width, " x ", report.height);
    const at::Tensor frame_image = image.to(device);
    const detect::PoseFrame pose = tracker.track(frame_image, double(report.frames) / options.frames_per_second);
    const int64_t index = report.frames++;
    if (!pose.found) {
      log.write({{"event", "frame"}, {"frame", index}, {"person", false}});
      continue;
    }
    // Frames are numbered as written, so the dataset's numbers have no gaps.
    const int64_t number = report.frames_with_person++;
    const data::SyntheticFramePaths paths =
        data::synthetic_frame_paths(building.string(), data::DatasetLayout::kNeuman, number);
    const at::Tensor keypoints = detect::wholebody_keypoints(pose, parts.face(frame_image, pose),
                                                             parts.hand(frame_image, pose, detect::HandSide::kLeft),
                                                             parts.hand(frame_image, pose, detect::HandSide::kRight))
                                     .cpu();
    const at::Tensor mask = (pose.mask > kMaskThreshold).to(at::kFloat).cpu();
    files.add([paths, image, mask, keypoints] {
      data::write_png(paths.image, image, false);
      data::write_png(paths.mask, mask, false);
      data::write_wholebody_keypoints(paths.keypoints, keypoints, false);
    });
    const std::string name = fs::path(paths.image).filename().string();
    cameras.push_back({name, camera});
    splits[data::interleaved_split(number)].push_back(name);
    nlohmann::json entry{
        {"event", "frame"}, {"frame", index}, {"person", true}, {"number", number}, {"score", pose.score}};
    if (pose.people > 1) {
      entry["people"] = pose.people;
      if (!options.quiet && report.frames_with_several == 0)
        std::fprintf(stderr, "sfgs prepare: frame %lld shows %lld people; following the largest\n", (long long)index,
                     (long long)pose.people);
      ++report.frames_with_several;
    }
    log.write(entry);
    if (!options.quiet && report.frames % kProgressEvery == 0)
      std::fprintf(
          stderr, "sfgs prepare: %lld frames, %lld with a person, %.1f frames/s\n", (long long)report.frames,
          (long long)report.frames_with_person,
          double(report.frames) / std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count());
  }
  files.finish();
  report.detection_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  TORCH_CHECK(report.frames > 0, "prepare: the input has no frames");
  TORCH_CHECK(report.frames_with_person > 0, "prepare: no person was found in any of the ", report.frames,
              " frames (the detector looks for one whole person, in view)");
  data::write_colmap_model(building.string(), cameras, false);
  for (const data::Split split : {data::Split::kTrain, data::Split::kVal, data::Split::kTest})
    data::write_split_file((building / (std::string(data::split_name(split)) + "_split.txt")).string(), splits[split],
                           false);
  log.write({{"event", "detection"},
             {"frames", report.frames},
             {"frames_with_person", report.frames_with_person},
             {"frames_with_several_people", report.frames_with_several},
             {"width", report.width},
             {"height", report.height},
             {"focal", report.focal},
             {"focal_source", report.focal_source},
             {"seconds", report.detection_seconds}});
  // The frames, masks, keypoints and camera are in place as one piece; the fit then writes its own files there
  // (atomically), so a failed fit leaves a dataset that `sfgs fit` can be run on again.
  if (fs::exists(out))
    TORCH_CHECK(remove_tree(out.string()), "prepare: could not remove '", out.string(), "' to replace it");
  fs::rename(building, out);
  if (options.fit) {
    fit::FitOptions f = options.fit_options;
    if (!f.truth.empty()) f.truth = fs::absolute(f.truth).string();
    f.data = f.out = out.string();
    f.device = options.device;
    f.focal = report.focal;
    f.quiet = options.quiet;
    report.fit = fit::run_fit(f);
  }
  return report;
}

}  // namespace sfgs::prepare
