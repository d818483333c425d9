// The sfgs command. `sfgs demo` renders the built-in Gaussian scene to a PNG and prints forward/backward timings.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <map>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/csrc/autograd/autograd.h>

#include "data/image_io.h"
#include "scene/builtin_scene.h"

namespace {

constexpr const char* kUsage = R"(usage: sfgs <command> [options]

commands:
  demo     render the built-in Gaussian scene to a PNG and print timings
           --out PATH        output image (default sfgs_demo.png)
           --gaussians N     number of Gaussians (default 60000)
           --width W         image width (default 640)
           --height H        image height (default 480)
           --repeats R       timed repetitions (default 5)
           --device DEV      cpu or cuda (default cpu)
           --force           replace an existing output file
  help     print this text
)";

struct Arguments {
  std::string command;
  std::map<std::string, std::string> values;
  bool force = false;
};

Arguments parse(int argc, char** argv) {
  Arguments a;
  a.command = argc > 1 ? argv[1] : "help";
  for (int i = 2; i < argc; ++i) {
    const std::string key = argv[i];
    if (key == "--force") {
      a.force = true;
    } else if (key.rfind("--", 0) == 0 && i + 1 < argc) {
      a.values[key.substr(2)] = argv[++i];
    } else {
      throw std::invalid_argument("unexpected argument '" + key + "'");
    }
  }
  return a;
}

int64_t integer_option(const Arguments& a, const std::string& name, int64_t fallback, int64_t lo, int64_t hi) {
  const auto it = a.values.find(name);
  if (it == a.values.end()) return fallback;
  size_t used = 0;
  int64_t v = 0;
  try {
    v = std::stoll(it->second, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != it->second.size() || v < lo || v > hi)
    throw std::invalid_argument("--" + name + " expects an integer in [" + std::to_string(lo) + ", " +
                                std::to_string(hi) + "], got '" + it->second + "'");
  return v;
}

double milliseconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

int run_demo(const Arguments& args) {
  const std::string out = args.values.count("out") ? args.values.at("out") : "sfgs_demo.png";
  const int64_t count = integer_option(args, "gaussians", 60000, 0, 50000000);
  const int64_t width = integer_option(args, "width", 640, 1, sfgs::kMaxImageSide);
  const int64_t height = integer_option(args, "height", 480, 1, sfgs::kMaxImageSide);
  const int64_t repeats = integer_option(args, "repeats", 5, 1, 1000);
  const std::string device = args.values.count("device") ? args.values.at("device") : "cpu";
  if (device != "cpu" && device != "cuda") throw std::invalid_argument("--device expects cpu or cuda, got " + device);
  if (device == "cuda" && !sfgs::cuda_backend_available())
    throw std::invalid_argument("--device cuda: this build of sfgs has no CUDA backend");

  sfgs::scene::GaussianScene s = sfgs::scene::demo_scene(count, width, height, 7, at::kFloat);
  const at::Device dev(device == "cuda" ? at::kCUDA : at::kCPU);
  sfgs::Gaussians& g = s.gaussians;
  for (at::Tensor* t : {&g.means, &g.scales, &g.rotations, &g.opacities, &g.features})
    *t = t->to(dev).set_requires_grad(true);
  s.background = s.background.to(dev);

  std::vector<double> forward_ms, backward_ms;
  sfgs::RenderResult result;
  for (int64_t r = 0; r <= repeats; ++r) {  // the first run warms up and is not timed
    auto start = std::chrono::steady_clock::now();
    result = sfgs::render(g, s.background, s.camera);
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

  sfgs::data::write_png(out, result.image.detach().cpu(), args.force);

  const int64_t visible = result.visible.sum().item<int64_t>();
  std::printf("sfgs demo: %lld Gaussians (%lld visible), %lld x %lld, device %s, %d threads\n", (long long)count,
              (long long)visible, (long long)width, (long long)height, device.c_str(), at::get_num_threads());
  std::printf("  forward  median %.2f ms (min %.2f, max %.2f) over %lld runs\n", forward_ms[forward_ms.size() / 2],
              forward_ms.front(), forward_ms.back(), (long long)repeats);
  std::printf("  backward median %.2f ms (min %.2f, max %.2f)\n", backward_ms[backward_ms.size() / 2],
              backward_ms.front(), backward_ms.back());
  std::printf("  mean alpha %.4f; wrote %s\n", result.alpha.mean().item<double>(), out.c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // OpenMP may start with one thread; use every core unless the user chose with OMP_NUM_THREADS.
  if (!std::getenv("OMP_NUM_THREADS")) at::set_num_threads(int(std::max(1u, std::thread::hardware_concurrency())));
  try {
    const Arguments args = parse(argc, argv);
    if (args.command == "demo") return run_demo(args);
    if (args.command == "help" || args.command == "--help" || args.command == "-h") {
      std::cout << kUsage;
      return 0;
    }
    std::cerr << "sfgs: unknown command '" << args.command << "'\n" << kUsage;
    return 2;
  } catch (const c10::Error& e) {
    std::cerr << "sfgs: " << e.what_without_backtrace() << "\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "sfgs: " << e.what() << "\n";
    return 1;
  }
}
