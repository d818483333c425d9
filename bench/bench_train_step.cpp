// Training-step benchmark: `steps` iterations of the real trainer (train::train_avatar) on a dataset folder with a
// config, after `warmup` iterations: the mean step and the peak GPU memory of a plain run (the trainer's own
// training_seconds; CUDA graphs as the config says), then the per-stage split of a step (StageClock, device
// synchronised per stage, which makes those steps eager).
// Usage: bench_train_step --data DIR --config FILE [--warmup N] [--steps N] [--out DIR] [--profile 1]
//   --profile 1: for Nsight Compute (`ncu --profile-from-start off --nvtx`): only the step after the warm-up is
//   profiled, its stages as NVTX ranges (profiled_range.h); no timing.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>

#include <ATen/ATen.h>
#include <torch/cuda.h>
#if defined(SFGS_WITH_CUDA)
#include <c10/cuda/CUDACachingAllocator.h>
#endif

#include "common/host_memory.h"
#include "data/dataset.h"
#include "flags.h"
#include "profiled_range.h"
#include "stage_clock.h"
#include "train/rounds.h"
#include "train/trainer.h"

namespace {

struct Arguments {
  std::string data, config, out = "/tmp/sfgs-bench-train-step";
  int64_t warmup = 20, steps = 100;
  bool profile = false;
};

[[noreturn]] void usage() {
  std::fprintf(stderr,
               "usage: bench_train_step --data DIR --config FILE [--warmup N] [--steps N] [--out DIR] [--profile 1]\n");
  std::exit(2);
}

Arguments parse(int argc, char** argv) {
  Arguments a;
  sfgs::bench::parse_flags(argc, argv, usage, [&](const std::string& flag, const std::string& value) {
    if (flag == "--data")
      a.data = value;
    else if (flag == "--config")
      a.config = value;
    else if (flag == "--out")
      a.out = value;
    else if (flag == "--warmup")
      a.warmup = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--steps")
      a.steps = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--profile")
      a.profile = value == "1";
    else
      return false;
    return true;
  });
  if (a.data.empty() || a.config.empty()) usage();
  return a;
}

// Records only the steps after the warm-up.
class SteadyStateClock : public sfgs::StageRecorder {
 public:
  SteadyStateClock(sfgs::bench::StageClock& clock, int64_t warmup) : clock_(clock), warmup_(warmup) {}
  void begin(const char* stage) override {
    if (std::string(stage) == kStep) ++steps_;
    if (steps_ > warmup_) clock_.begin(stage);
  }
  void end(const char* stage) override {
    if (steps_ > warmup_) clock_.end(stage);
  }
  static constexpr const char* kStep = "train: step";

 private:
  sfgs::bench::StageClock& clock_;
  int64_t warmup_, steps_ = 0;
};

// Profiles the step after the warm-up: the profiler collects from its start to its end, its stages NVTX ranges.
class ProfiledStep : public sfgs::StageRecorder {
 public:
  explicit ProfiledStep(int64_t warmup) : warmup_(warmup) {}
  void begin(const char* stage) override {
    if (std::string(stage) == SteadyStateClock::kStep && ++steps_ == warmup_ + 1) range_.emplace("profiled step");
    if (range_) stages_.begin(stage);
  }
  void end(const char* stage) override {
    if (!range_) return;
    stages_.end(stage);
    if (std::string(stage) == SteadyStateClock::kStep) range_.reset();
  }

 private:
  int64_t warmup_, steps_ = 0;
  sfgs::bench::NvtxStages stages_;
  std::optional<sfgs::bench::ProfiledRange> range_;
};

}  // namespace

int main(int argc, char** argv) {
  sfgs::reuse_freed_host_memory();
  const Arguments args = parse(argc, argv);
  const sfgs::data::Dataset dataset = sfgs::data::read_dataset(args.data);
  sfgs::train::TrainConfig config = sfgs::train::TrainConfig::from_yaml_file(args.config);
  const bool cuda = config.device == "cuda";
  const int64_t total = args.warmup + args.steps;
  config.schedule.iterations = total;
  config.log_every = config.validate_every = config.checkpoint_every = total;
  sfgs::train::TrainOptions options;
  options.overwrite = true;
  options.progress = false;
  std::filesystem::create_directories(args.out);

  if (args.profile) {
    config.schedule.iterations = args.warmup + 1;
    ProfiledStep profiled(args.warmup);
    const sfgs::ScopedStageRecorder recording(&profiled);
    sfgs::train::train_avatar(dataset, config, sfgs::train::RunFolder{args.out + "/profiled"}, options);
    std::printf("profiled training step %ld\n", long(args.warmup + 1));
    return 0;
  }
  // Plain run: the trainer's own step time, and its peak memory.
#if defined(SFGS_WITH_CUDA)
  if (cuda) {
    at::empty({1}, at::kCUDA);  // the allocator's statistics exist from the first allocation on
    c10::cuda::CUDACachingAllocator::resetPeakStats(0);
  }
#endif
  const sfgs::train::TrainSummary plain =
      sfgs::train::train_avatar(dataset, config, sfgs::train::RunFolder{args.out + "/plain"}, options);
  std::printf("sfgs training-step benchmark: %s, %s, %ld steps after %ld warm-up\n", args.data.c_str(),
              config.device.c_str(), long(args.steps), long(args.warmup));
  std::printf("  mean step (trainer's training_seconds, warm-up included, CUDA graphs %s): %.2f ms\n",
              cuda && config.schedule.cuda_graphs ? "on" : "off", 1000 * plain.training_seconds / double(total));
#if defined(SFGS_WITH_CUDA)
  if (cuda) {
    const auto stats = c10::cuda::CUDACachingAllocator::getDeviceStats(0);
    const size_t aggregate = 0;  // StatType::AGGREGATE, whose namespace differs between LibTorch versions
    std::printf("  peak GPU memory: %.2f GB allocated, %.2f GB reserved\n",
                double(stats.allocated_bytes[aggregate].peak) / 1e9,
                double(stats.reserved_bytes[aggregate].peak) / 1e9);
  }
#endif
  sfgs::bench::StageClock clock(cuda);
  SteadyStateClock steady(clock, args.warmup);
  {
    const sfgs::ScopedStageRecorder recording(&steady);
    sfgs::train::train_avatar(dataset, config, sfgs::train::RunFolder{args.out + "/staged"}, options);
  }
  std::printf("  stages of an eager step (synchronised per stage):\n");
  clock.print(args.steps, SteadyStateClock::kStep);
  return 0;
}
