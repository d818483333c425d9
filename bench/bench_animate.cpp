// Animation benchmark: pose -> image of an avatar through animate::Animator (csrc/animate/animator.h), at several
// image sizes. Per size: the median frame time and frames/s of graph frames (one CUDA graph replay each) and of eager
// frames, and the per-stage split of an eager frame (StageClock, device synchronised per stage).
// Usage: bench_animate [--device cpu|cuda] [--shared DIR] [--levels L] [--sizes 800x1200,540x960] [--frames N]
//   --shared DIR: the Anny stand-in body of DIR/bodies (with MANO hands and face ids) instead of the procedural body.
// The avatar is untrained (same work per frame as a trained one of its configuration) and shows the motion of a
// smooth sweep between two random poses, framed by a camera in front of it.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>
#include <torch/cuda.h>

#include "animate/animator.h"
#include "body/skeleton.h"
#include "common/host_memory.h"
#include "stage_clock.h"

namespace {

using sfgs::body::SmplxPose;

struct Arguments {
  std::string device = "cuda";
  std::string shared;
  int64_t levels = 2;
  std::vector<std::pair<int64_t, int64_t>> sizes{{800, 1200}, {540, 960}};
  int frames = 200;
};

[[noreturn]] void usage() {
  std::fprintf(stderr, "usage: bench_animate [--device cpu|cuda] [--shared DIR] [--levels L] [--sizes WxH,...] "
                       "[--frames N]\n");
  std::exit(2);
}

Arguments parse(int argc, char** argv) {
  Arguments a;
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (i + 1 >= argc) usage();
    const std::string value = argv[++i];
    if (flag == "--device") a.device = value;
    else if (flag == "--shared") a.shared = value;
    else if (flag == "--levels") a.levels = std::max(0, std::atoi(value.c_str()));
    else if (flag == "--frames") a.frames = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--sizes") {
      a.sizes.clear();
      std::stringstream list(value);
      for (std::string item; std::getline(list, item, ',');) {
        long w = 0, h = 0;
        if (std::sscanf(item.c_str(), "%ldx%ld", &w, &h) != 2 || w <= 0 || h <= 0) usage();
        a.sizes.push_back({w, h});
      }
    } else usage();
  }
  return a;
}

SmplxPose random_pose(uint64_t seed) {
  at::Generator generator = at::detail::createCPUGenerator(seed);
  const auto uniform = [&](at::IntArrayRef shape, double bound) {
    return at::empty(shape).uniform_(-bound, bound, generator);
  };
  SmplxPose p;
  p.global_orient = uniform({3}, 0.2);
  p.body_pose = uniform({sfgs::body::kSmplxBodyJointCount, 3}, 0.4);
  p.jaw_pose = uniform({3}, 0.2);
  p.left_hand_pose = uniform({sfgs::body::kHandJointCount, 3}, 0.4);
  p.right_hand_pose = uniform({sfgs::body::kHandJointCount, 3}, 0.4);
  p.expression = uniform({10}, 1.0);
  p.transl = uniform({3}, 0.05);
  return p;
}

// The pose a fraction `t` of the way from a to b (field by field; a smooth motion for the benchmark).
SmplxPose blend(const SmplxPose& a, const SmplxPose& b, double t) {
  SmplxPose p;
  for (const SmplxPose::Field& f : SmplxPose::fields())
    if ((a.*(f.member)).defined()) p.*(f.member) = a.*(f.member) * (1 - t) + b.*(f.member) * t;
  return p;
}

// A camera in front of the avatar (+z, y up in the body's frame) that frames its rest-pose points.
sfgs::Camera framing_camera(sfgs::model::Avatar& avatar, const SmplxPose& pose, int64_t width, int64_t height) {
  at::NoGradGuard no_grad;
  avatar->clear_cache();
  const at::Tensor points = avatar->forward(pose, std::nullopt).means.cpu().to(at::kDouble);
  const at::Tensor lo = std::get<0>(points.min(0)), hi = std::get<0>(points.max(0)), centre = (lo + hi) / 2;
  const double focal = 1.2 * double(std::max(width, height));
  const double fill = 0.85;
  const double distance = focal * std::max((hi[1] - lo[1]).item<double>() / (fill * double(height)),
                                           (hi[0] - lo[0]).item<double>() / (fill * double(width))) +
                          (hi[2] - lo[2]).item<double>();
  sfgs::Camera c = sfgs::Camera::looking_forward(focal, width, height);
  // x stays, y and z flip (a rotation): the camera looks along -z of the body's frame from `distance` in front.
  c.world_to_camera = {1, 0, 0, -centre[0].item<double>(), 0, -1, 0, centre[1].item<double>(),
                       0, 0, -1, centre[2].item<double>() + distance, 0, 0, 0, 1};
  return c;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Milliseconds of each of `frames` frames of the sweep, the device synchronised after each (the Animator's graph
// frames end with a wait for the image anyway).
std::vector<double> time_frames(sfgs::animate::Animator& animator, const SmplxPose& a, const SmplxPose& b, int frames,
                                bool cuda) {
  std::vector<double> ms;
  for (int k = 0; k < frames; ++k) {
    const SmplxPose pose = blend(a, b, double(k) / double(frames));
    const auto start = std::chrono::steady_clock::now();
    animator.render(pose);
    if (cuda) torch::cuda::synchronize();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  }
  return ms;
}

}  // namespace

int main(int argc, char** argv) {
  sfgs::reuse_freed_host_memory();
  const Arguments args = parse(argc, argv);
  const bool cuda = args.device == "cuda";
  if (!cuda && args.device != "cpu") usage();
  if (cuda && !torch::cuda::is_available()) {
    std::fprintf(stderr, "bench_animate: --device cuda, but this LibTorch sees no CUDA device\n");
    return 1;
  }
  const std::string bodies = args.shared + "/bodies/";
  const sfgs::model::AvatarBody body =
      args.shared.empty()
          ? sfgs::model::AvatarBody::procedural()
          : sfgs::model::AvatarBody::load(bodies + "anny_smplx_layout.npz", bodies + "anny_mano_left.npz",
                                          bodies + "anny_mano_right.npz", bodies + "MANO_SMPLX_vertex_ids.npz",
                                          bodies + "FLAME_SMPLX_vertex_ids.npy");
  sfgs::model::AvatarConfig config;
  config.subdivision_levels = args.levels;
  sfgs::model::Avatar avatar(body, at::zeros({10}), config);
  avatar->to(cuda ? at::kCUDA : at::kCPU);
  avatar->eval();
  const SmplxPose a = random_pose(11), b = random_pose(12);
  std::printf("sfgs animation benchmark: %s body, %ld Gaussians, %s, %d frames per size (median)\n",
              args.shared.empty() ? "procedural" : "Anny", long(avatar->gaussian_count()), args.device.c_str(),
              args.frames);
  for (const auto& [width, height] : args.sizes) {
    const sfgs::Camera camera = framing_camera(avatar, a, width, height);
    const at::Tensor white = at::ones({3});
    sfgs::animate::AnimatorOptions eager_options;
    eager_options.use_graph = false;
    sfgs::animate::Animator eager(avatar, camera, white, eager_options);
    time_frames(eager, a, b, 3, cuda);  // warm-up
    const double eager_ms = median(time_frames(eager, a, b, args.frames, cuda));
    sfgs::bench::StageClock clock(cuda);
    {
      const sfgs::ScopedStageRecorder recording(&clock);
      for (int k = 0; k < 10; ++k) {
        const sfgs::StageScope frame("frame (eager, synchronised per stage)");
        eager.render(blend(a, b, k / 10.0));
      }
    }
    std::printf("%ldx%ld\n", long(width), long(height));
    std::printf("  eager frame: %.3f ms (%.0f frames/s); stages of an eager frame:\n", eager_ms, 1000 / eager_ms);
    clock.print(10, "frame (eager, synchronised per stage)");
    if (cuda) {
      sfgs::animate::Animator graphed(avatar, camera, white);
      time_frames(graphed, a, b, 3, cuda);  // captures
      const double graph_ms = median(time_frames(graphed, a, b, args.frames, cuda));
      const at::Tensor from_graph = graphed.render(a).clone(), from_eager = eager.render(a);
      const double difference = (from_graph - from_eager).abs().max().item<double>();
      const sfgs::animate::AnimatorStats& s = graphed.stats();
      std::printf("  graph frame: %.3f ms (%.0f frames/s); %ld captures, %ld budget overflows, %ld intersections "
                  "(budget %ld); largest difference to the eager frame %.2e\n",
                  graph_ms, 1000 / graph_ms, long(s.captures), long(s.budget_overflows), long(s.intersections),
                  long(s.budget), difference);
    }
  }
  return 0;
}
