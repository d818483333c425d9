// Avatar benchmark: forward time of the SFGS avatar (csrc/model/avatar.h) in the paper's configuration on the
// procedural body, subdivided to the level whose point count is closest to SMPL-X's 167,390.
// Usage: bench_avatar [--device cpu|cuda] [--repeats N] [--levels L]
// Prints the parameter count (per module), then median (min-max) milliseconds of: training-mode forward (autograd
// recording), its backward, inference forward without the cache, building the cache, and cached inference forward
// (new pose every call; at a fixed time, and at a new time every call).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include <ATen/CPUGeneratorImpl.h>
#include <ATen/Functions.h>
#include <ATen/Parallel.h>
#include <ATen/TensorOperators.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <torch/cuda.h>

#include "common/host_memory.h"
#include "body/mesh.h"
#include "body/skeleton.h"
#include "model/avatar.h"
#include "flags.h"

namespace {

constexpr int64_t kSmplxPointCount = 167390;  // SMPL-X subdivided twice (ExAvatar, SFGS)

struct Arguments {
  std::string device = "cpu";
  int repeats = 5;
  int64_t levels = -1;  // -1: closest to kSmplxPointCount
};

[[noreturn]] void usage() {
  std::fprintf(stderr, "usage: bench_avatar [--device cpu|cuda] [--repeats N] [--levels L]\n");
  std::exit(2);
}

Arguments parse(int argc, char** argv) {
  Arguments a;
  sfgs::bench::parse_flags(argc, argv, usage, [&](const std::string& flag, const std::string& value) {
    if (flag == "--device")
      a.device = value;
    else if (flag == "--repeats")
      a.repeats = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--levels")
      a.levels = std::max(0, std::atoi(value.c_str()));
    else
      return false;
    return true;
  });
  return a;
}

// Point counts of the body at 0, 1, ... subdivision levels until past the target; the level closest to it.
int64_t closest_level(const sfgs::body::SmplxModelData& body) {
  int64_t vertices = body.v_template.size(0), best = 0;
  double best_distance = std::abs(double(vertices - kSmplxPointCount));
  at::Tensor faces = body.faces;
  for (int64_t level = 1; vertices < kSmplxPointCount; ++level) {
    const sfgs::body::MidpointSubdivision step(faces, vertices);
    vertices = step.fine_vertex_count();
    faces = step.fine_faces();
    const double distance = std::abs(double(vertices - kSmplxPointCount));
    if (distance < best_distance) best = level, best_distance = distance;
  }
  return best;
}

sfgs::body::SmplxPose pose_at(int64_t index) {
  at::Generator generator = at::detail::createCPUGenerator(static_cast<uint64_t>(1000 + index));
  const auto uniform = [&](at::IntArrayRef shape, double bound) {
    return at::empty(shape).uniform_(-bound, bound, generator);
  };
  sfgs::body::SmplxPose p;
  p.global_orient = uniform({3}, 0.5);
  p.body_pose = uniform({sfgs::body::kSmplxBodyJointCount, 3}, 0.5);
  p.jaw_pose = uniform({3}, 0.2);
  p.left_hand_pose = uniform({sfgs::body::kHandJointCount, 3}, 0.5);
  p.right_hand_pose = uniform({sfgs::body::kHandJointCount, 3}, 0.5);
  p.expression = uniform({10}, 1.0);
  p.transl = uniform({3}, 0.5);
  return p;
}

struct Timing {
  double median, min, max;
};

// Runs f once to warm up, then `repeats` times; each call's milliseconds come from f itself.
Timing measure(int repeats, const std::function<double(int)>& f) {
  f(-1);
  std::vector<double> ms;
  for (int r = 0; r < repeats; ++r) ms.push_back(f(r));
  std::sort(ms.begin(), ms.end());
  return Timing{ms[ms.size() / 2], ms.front(), ms.back()};
}

void print(const char* what, const Timing& t) {
  std::printf("  %-44s %10.1f ms  (%.1f - %.1f)\n", what, t.median, t.min, t.max);
}

// Wall-clock milliseconds that include the device's queued work (synchronising first on CUDA).
struct Clock {
  c10::Device device;
  std::chrono::steady_clock::time_point now() const {
    if (device.is_cuda()) torch::cuda::synchronize();
    return std::chrono::steady_clock::now();
  }
  double since(std::chrono::steady_clock::time_point start) const {
    return std::chrono::duration<double, std::milli>(now() - start).count();
  }
};

void print_model(const sfgs::model::AvatarBody& body, const sfgs::model::AvatarConfig& config,
                 sfgs::model::Avatar& avatar, const Arguments& args, double build_ms) {
  int64_t parameters = 0;
  for (const at::Tensor& p : avatar->parameters()) parameters += p.numel();
  std::printf(
      "sfgs avatar benchmark: procedural body (%ld vertices) subdivided %ld times = %ld Gaussians "
      "(SMPL-X at 2 levels: %ld), %s, %d threads, median (min-max) of %d runs after 1 warm-up\n",
      long(body.smplx.v_template.size(0)), long(config.subdivision_levels), long(avatar->gaussian_count()),
      long(kSmplxPointCount), args.device.c_str(), at::get_num_threads(), args.repeats);
  std::printf("built in %.0f ms; parameters: %ld (formula: %ld)\n", build_ms, long(parameters),
              long(sfgs::model::parameter_count(config, body.has_mano)));
  for (const auto& child : avatar->named_children()) {
    int64_t count = 0;
    for (const at::Tensor& p : child.value()->parameters()) count += p.numel();
    if (count > 0) std::printf("  %-20s %10ld\n", child.key().c_str(), long(count));
  }
}

void bench_training(sfgs::model::Avatar& avatar, const Clock& clock, int repeats) {
  avatar->train();
  const auto loss_of = [](const sfgs::model::AvatarOutput& out) {
    return out.means.sum() + out.covariances.sum() + out.colours.sum();
  };
  print("training forward (autograd recording)", measure(repeats, [&](int r) {
          const auto start = clock.now();
          const at::Tensor loss = loss_of(avatar->forward(pose_at(r), 0.1));
          return clock.since(start);
        }));
  print("training backward", measure(repeats, [&](int r) {
          const at::Tensor loss = loss_of(avatar->forward(pose_at(r), 0.1));
          const auto start = clock.now();
          torch::autograd::backward({loss});
          return clock.since(start);
        }));
  avatar->zero_grad();
}

void bench_inference(sfgs::model::Avatar& avatar, const Clock& clock, int repeats) {
  avatar->eval();
  at::NoGradGuard no_grad;
  const auto timed = [&](const std::function<void(int)>& f) {
    return measure(repeats, [&](int r) {
      const auto start = clock.now();
      f(r);
      return clock.since(start);
    });
  };
  print("inference forward, no cache", timed([&](int r) { avatar->forward(pose_at(r), 0.1); }));
  print("cache_static_features()", timed([&](int) { avatar->cache_static_features(); }));
  print("cached inference forward, fixed time", timed([&](int r) { avatar->forward(pose_at(r), 0.1); }));
  print("cached inference forward, new time each call",
        timed([&](int r) { avatar->forward(pose_at(r), -0.9 + 0.01 * (r + 2)); }));
}

}  // namespace

int main(int argc, char** argv) {
  sfgs::reuse_freed_host_memory();
  const Arguments args = parse(argc, argv);
  if (args.device != "cpu" && args.device != "cuda") {
    std::fprintf(stderr, "bench_avatar: --device must be cpu or cuda, got '%s'\n", args.device.c_str());
    return 2;
  }
  if (args.device == "cuda" && !torch::cuda::is_available()) {
    std::fprintf(stderr, "bench_avatar: --device cuda, but this LibTorch sees no CUDA device\n");
    return 1;
  }
  if (!std::getenv("OMP_NUM_THREADS")) at::set_num_threads(int(std::max(1u, std::thread::hardware_concurrency())));
  const Clock clock{c10::Device(args.device == "cuda" ? c10::kCUDA : c10::kCPU)};

  const sfgs::model::AvatarBody body = sfgs::model::AvatarBody::procedural();
  sfgs::model::AvatarConfig config;
  config.subdivision_levels = args.levels >= 0 ? args.levels : closest_level(body.smplx);
  const auto build_start = std::chrono::steady_clock::now();
  sfgs::model::Avatar avatar(body, at::zeros({10}), config);
  const double build_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - build_start).count();
  avatar->to(clock.device);
  print_model(body, config, avatar, args, build_ms);
  bench_training(avatar, clock, args.repeats);
  bench_inference(avatar, clock, args.repeats);
  return 0;
}
