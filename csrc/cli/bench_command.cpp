// `sfgs bench`: renders the built-in Gaussian scene and prints forward and backward timings.
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/csrc/autograd/autograd.h>

#include "cli/commands.h"
#include "data/image_io.h"
#include "scene/builtin_scene.h"
#include "ops/splat/constants.h"

namespace sfgs::cli {
namespace {

double milliseconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

int run_bench(Arguments& args) {
  const int64_t count = args.integer("gaussians", 60000, 0, 50000000);
  const int64_t width = args.integer("width", 640, 1, kMaxImageSide);
  const int64_t height = args.integer("height", 480, 1, kMaxImageSide);
  const int64_t repeats = args.integer("repeats", 5, 1, 1000);
  const std::string device = args.text("device", "cpu");
  const std::string out = args.text("out", "");
  const bool force = args.flag("force");
  args.finish();
  // Checked before the work, and so that a mistyped --out never writes a PNG over a checkpoint or a video.
  std::string extension = std::filesystem::path(out).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  if (!out.empty() && extension != ".png")
    throw std::invalid_argument("--out names the PNG image the bench writes (FILE.png), got '" + out + "'");
  if (device != "cpu" && device != "cuda") throw std::invalid_argument("--device expects cpu or cuda, got " + device);
  if (device == "cuda" && !cuda_backend_available())
    throw std::invalid_argument("--device cuda: this build of sfgs has no CUDA backend");

  scene::GaussianScene s = scene::demo_scene(count, width, height, 7, at::kFloat);
  const at::Device dev(device == "cuda" ? at::kCUDA : at::kCPU);
  Gaussians& g = s.gaussians;
  for (at::Tensor* t : {&g.means, &g.scales, &g.rotations, &g.opacities, &g.features})
    *t = t->to(dev).set_requires_grad(true);
  s.background = s.background.to(dev);

  std::vector<double> forward_ms, backward_ms;
  RenderResult result;
  for (int64_t r = 0; r <= repeats; ++r) {  // the first run warms up and is not timed
    auto start = std::chrono::steady_clock::now();
    result = render(g, s.background, s.camera);
    if (dev.is_cuda()) result.image.sum().item<float>();
    const double fwd = milliseconds_since(start);
    start = std::chrono::steady_clock::now();
    torch::autograd::backward({result.image.sum()});
    if (dev.is_cuda()) g.means.grad().sum().item<float>();
    const double bwd = milliseconds_since(start);
    if (r > 0) {
      forward_ms.push_back(fwd);
      backward_ms.push_back(bwd);
    }
  }
  std::sort(forward_ms.begin(), forward_ms.end());
  std::sort(backward_ms.begin(), backward_ms.end());
  if (!out.empty()) data::write_png(out, result.image.detach().cpu(), force);
  std::printf("sfgs bench: %lld Gaussians (%lld visible), %lld x %lld, device %s, %d threads\n", (long long)count,
              (long long)result.visible.sum().item<int64_t>(), (long long)width, (long long)height, device.c_str(),
              at::get_num_threads());
  std::printf("  forward  median %.2f ms (min %.2f, max %.2f) over %lld runs\n", forward_ms[forward_ms.size() / 2],
              forward_ms.front(), forward_ms.back(), (long long)repeats);
  std::printf("  backward median %.2f ms (min %.2f, max %.2f)\n", backward_ms[backward_ms.size() / 2],
              backward_ms.front(), backward_ms.back());
  if (!out.empty()) std::printf("  wrote %s\n", out.c_str());
  return 0;
}

}  // namespace sfgs::cli
