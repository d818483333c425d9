// Pose-fitting benchmark (train/pose_fit.h): what one loss evaluation of a trained avatar's pose fit costs, by what it
// compares, and what whole fits cost. On a run folder of `sfgs train` and the dataset it was trained on, for the first
// --frames frames of --split:
//  - per evaluation kind, the mean time of --evaluations recorded evaluations (upload, replay, read of the loss and
//    gradient, as L-BFGS sees them; CUDA) or eager ones: the fine stage on the whole image and on the person's crop
//    (person_crop), the crop without LPIPS, and the crop with the coarser stages' L1 and silhouette;
//  - PoseFitter::fit of each frame with the alignment passes' budget (--fit-evaluations, default 60): evaluations,
//    seconds, and the loss from its start.
// Usage: bench_pose_fit --run DIR [--split test|val|train] [--frames N] [--evaluations N] [--fit-evaluations N]
//                       [--device cuda|cpu] [--profile 1]
//   --profile 1: for Nsight Compute (`ncu --profile-from-start off --nvtx`): one eager fine evaluation of the first
//   frame's crop with the skeleton's gradient (as the alignment passes take it) after a warm-up, its forward stages
//   as NVTX ranges (profiled_range.h); no timing.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <utility>

#include <ATen/ATen.h>
#include <torch/cuda.h>

#include "common/device_graph.h"
#include "common/host_memory.h"
#include "common/matmul_precision.h"
#include "common/stage_timer.h"
#include "train/pose_fit.h"
#include "train/pose_fit_evaluation.h"
#include "train/run_folder.h"
#include "flags.h"
#include "profiled_range.h"

namespace {

using namespace sfgs;

struct Arguments {
  std::string run, split = "test", device = "cuda";
  int64_t frames = 4, evaluations = 100, fit_evaluations = 60;
  bool profile = false;
};

[[noreturn]] void usage() {
  std::fprintf(stderr,
               "usage: bench_pose_fit --run DIR [--split test|val|train] [--frames N] [--evaluations N] "
               "[--fit-evaluations N] [--device cuda|cpu] [--profile 1]\n");
  std::exit(2);
}

Arguments parse(int argc, char** argv) {
  Arguments a;
  bench::parse_flags(argc, argv, usage, [&](const std::string& flag, const std::string& value) {
    if (flag == "--run")
      a.run = value;
    else if (flag == "--split")
      a.split = value;
    else if (flag == "--device")
      a.device = value;
    else if (flag == "--frames")
      a.frames = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--evaluations")
      a.evaluations = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--fit-evaluations")
      a.fit_evaluations = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--profile")
      a.profile = value == "1";
    else
      return false;
    return true;
  });
  if (a.run.empty()) usage();
  return a;
}

data::Split split_named(const std::string& name) {
  for (const data::Split s : {data::Split::kTrain, data::Split::kVal, data::Split::kTest})
    if (name == data::split_name(s)) return s;
  usage();
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// One eager evaluation of `frame`: its loss, after its gradient has been computed.
double eager_evaluation(model::Avatar& avatar, const train::FitLoss& loss, const train::FitFrame& frame,
                        const at::Tensor& correction, bool run_loss) {
  const at::Tensor moving = correction.to(frame.image.device()).requires_grad_(true);
  const at::Tensor value = loss(avatar, frame, moving, run_loss);
  value.backward();
  return value.item<double>();
}

// Mean seconds of one evaluation of `frame`, recorded where the device can record, else eager.
double evaluation_seconds(model::Avatar& avatar, const train::FitLoss& loss, const train::FitFrame& frame,
                          bool run_loss, int64_t evaluations) {
  const at::Device device = frame.image.device();
  const at::Tensor correction = 0.01 * at::randn({train::kCorrectionWidth});
  if (device.is_cuda() && device_graphs_available()) {
    train::PoseFitGraphs graphs(avatar, loss, device);
    graphs.load(frame, run_loss);
    for (int k = 0; k < 3; ++k) graphs.evaluate(correction);  // measure the budget, record
    const auto start = std::chrono::steady_clock::now();
    for (int64_t k = 0; k < evaluations; ++k) graphs.evaluate(correction);
    return seconds_since(start) / double(evaluations);
  }
  eager_evaluation(avatar, loss, frame, correction, run_loss);
  const auto start = std::chrono::steady_clock::now();
  for (int64_t k = 0; k < evaluations; ++k) eager_evaluation(avatar, loss, frame, correction, run_loss);
  return seconds_since(start) / double(evaluations);
}

}  // namespace

int main(int argc, char** argv) {
  const Arguments args = parse(argc, argv);
  reuse_freed_host_memory();
  const at::Device device(args.device);
  if (args.profile && !device.is_cuda()) {
    std::fprintf(stderr, "bench_pose_fit: --profile 1 profiles CUDA kernels: it needs --device cuda\n");
    return 2;
  }
  if (device.is_cuda() && !torch::cuda::is_available()) {
    std::fprintf(stderr, "bench_pose_fit: no CUDA device\n");
    return 1;
  }
  train::TrainedAvatar trained = train::load_trained_avatar(train::RunFolder{args.run}, device);
  const data::Dataset dataset = train::read_run_dataset(trained, "");
  const std::vector<int64_t>& frames = dataset.split(split_named(args.split));
  if (frames.empty()) {
    std::fprintf(stderr, "bench_pose_fit: the split %s has no frames\n", args.split.c_str());
    return 1;
  }
  // The networks' products as the run's training steps took them (and so its alignment passes).
  const Tf32MatmulScope products(device.is_cuda() && trained.config.schedule.tf32_matmul);
  model::Avatar& avatar = trained.avatar;
  avatar->eval();
  avatar->cache_static_features();
  train::LossWeights with_lpips = trained.config.loss, without_lpips = trained.config.loss;
  without_lpips.use_lpips = false;
  const train::ImageLoss image_loss(with_lpips, device), image_loss_without_lpips(without_lpips, device);
  const train::FitLoss loss(image_loss, nullptr, 0), loss_without_lpips(image_loss_without_lpips, nullptr, 0);
  const train::FitLoss skeleton_loss(image_loss, nullptr, 0, model::PoseGradient::kSkeleton);
  std::printf("bench_pose_fit: %s, %lld Gaussians, %s split, LPIPS %s\n", device.str().c_str(),
              static_cast<long long>(avatar->gaussian_count()), args.split.c_str(),
              image_loss.lpips_status().empty() ? "loaded" : image_loss.lpips_status().c_str());

  if (args.profile) {
    const int64_t f = frames[0];
    const train::PoseFitTarget target = train::pose_fit_target(dataset, f, device, false);
    const train::FitFrame crop = train::fit_frame(avatar, dataset.frames[size_t(f)].pose, target, true);
    const at::Tensor correction = 0.01 * at::randn({train::kCorrectionWidth});
    for (int k = 0; k < 3; ++k) eager_evaluation(avatar, skeleton_loss, crop, correction, true);
    bench::NvtxStages stages;
    const ScopedStageRecorder recording(&stages);
    const bench::ProfiledRange range("pose fit evaluation");
    eager_evaluation(avatar, skeleton_loss, crop, correction, true);
    std::printf("profiled one eager fine evaluation of %s\n", dataset.frames[size_t(f)].name.c_str());
    return 0;
  }

  const int64_t count = std::min<int64_t>(args.frames, int64_t(frames.size()));
  for (int64_t k = 0; k < count; ++k) {
    const int64_t f = frames[size_t(k)];
    const data::FrameRecord& record = dataset.frames[size_t(f)];
    const train::PoseFitTarget target = train::pose_fit_target(dataset, f, device, false);
    const train::FitFrame whole = train::fit_frame(avatar, record.pose, target, false);
    const train::FitFrame crop = train::fit_frame(avatar, record.pose, target, true);
    const auto ms = [&](const train::FitLoss& l, const train::FitFrame& frame, bool run_loss) {
      return 1000 * evaluation_seconds(avatar, l, frame, run_loss, args.evaluations);
    };
    std::printf(
        "  %s: crop %lldx%lld of %lldx%lld (%.0f %%); ms an evaluation: fine whole %.2f, fine crop %.2f, "
        "crop without LPIPS %.2f, crop L1 %.2f, crop with the skeleton's gradient %.2f\n",
        record.name.c_str(), static_cast<long long>(crop.camera.width), static_cast<long long>(crop.camera.height),
        static_cast<long long>(whole.camera.width), static_cast<long long>(whole.camera.height), 100 * crop.pixel_share,
        ms(loss, whole, true), ms(loss, crop, true), ms(loss_without_lpips, crop, true), ms(loss, crop, false),
        ms(skeleton_loss, crop, true));
  }

  // Whole fits as test-time fitting runs them, and as an alignment pass does (train/pose_refinement.cpp).
  train::PoseFitOptions test_time;
  test_time.iterations = args.fit_evaluations;
  test_time.loss = with_lpips;
  train::PoseFitOptions alignment = test_time;
  alignment.gradient = model::PoseGradient::kSkeleton;
  alignment.stall_share = train::kAlignmentStallShare;
  const at::Tensor zero = at::zeros({train::kCorrectionWidth});
  for (const auto& [name, options] : {std::pair{"test-time", test_time}, {"alignment", alignment}}) {
    train::PoseFitter fitter(options, device, nullptr);
    for (int64_t k = 0; k < count; ++k) {
      const int64_t f = frames[size_t(k)];
      const train::PoseFitTarget target = train::pose_fit_target(dataset, f, device, false);
      const auto start = std::chrono::steady_clock::now();
      const train::PoseFitResult r = fitter.fit(avatar, dataset.frames[size_t(f)].pose, target, zero);
      const double seconds = seconds_since(start);
      std::printf("  %s fit %s: %lld evaluations in %.3f s (%.2f ms each), loss %.5f -> %.5f, recorded %d\n", name,
                  dataset.frames[size_t(f)].name.c_str(), static_cast<long long>(r.evaluations), seconds,
                  1000 * seconds / double(r.evaluations), r.start_loss, r.loss, int(r.recorded));
    }
  }
  return 0;
}
