// Metric benchmark (CPU): SSIM forward + backward (the training loss), LPIPS forward and forward + backward for
// both networks, one evaluation-protocol frame, and the geometry metrics on two 167,390-point surfaces (SFGS's
// Gaussian count). LPIPS uses random weights of the real shapes (timings do not depend on the values).
// Usage: bench_metrics [repeats=3]. Prints median (min-max) milliseconds.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/csrc/autograd/autograd.h>

#include "common/host_memory.h"
#include "metrics/evaluation.h"
#include "metrics/geometry_metrics.h"
#include "metrics/image_metrics.h"
#include "metrics/lpips.h"

namespace {

using namespace sfgs::metrics;

void report(const std::string& what, int repeats, const std::function<void()>& run) {
  run();  // warm-up
  std::vector<double> ms;
  for (int r = 0; r < repeats; ++r) {
    const auto start = std::chrono::steady_clock::now();
    run();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  }
  std::sort(ms.begin(), ms.end());
  std::printf("%-58s %10.1f (%.1f-%.1f)\n", what.c_str(), ms[ms.size() / 2], ms.front(), ms.back());
}

Lpips random_network(LpipsNet net) {
  std::map<std::string, at::Tensor> weights;
  for (const auto& [name, shape] : lpips_weight_shapes(net)) weights.emplace(name, at::randn(shape) * 0.05);
  return Lpips(net, weights);
}

}  // namespace

int main(int argc, char** argv) {
  sfgs::reuse_freed_host_memory();
  const int repeats = argc > 1 ? std::max(1, std::atoi(argv[1])) : 3;
  if (!std::getenv("OMP_NUM_THREADS")) at::set_num_threads(int(std::max(1u, std::thread::hardware_concurrency())));
  std::printf("sfgs metric benchmark (CPU, %d threads): median (min-max) ms of %d runs after 1 warm-up\n",
              at::get_num_threads(), repeats);
  at::manual_seed(0);

  for (const auto& [h, w] : std::vector<std::pair<int64_t, int64_t>>{{512, 512}, {1080, 1920}}) {
    const std::string size = std::to_string(h) + "x" + std::to_string(w);
    const at::Tensor a = at::rand({h, w, 3}), b = at::rand({h, w, 3});
    for (SsimBorder border : {SsimBorder::zero, SsimBorder::reflect}) {
      const std::string name = border == SsimBorder::zero ? "zero" : "reflect";
      report("SSIM " + name + " float32 forward " + size, repeats, [&] { ssim(a, b, border); });
      report("SSIM " + name + " float32 forward+backward " + size, repeats, [&] {
        const at::Tensor p = a.clone().requires_grad_(true);
        torch::autograd::grad({ssim(p, b, border)}, {p});
      });
    }
    report("SSIM reflect float64 forward " + size + " (evaluation)", repeats,
           [&] { ssim(a.to(at::kDouble), b.to(at::kDouble), SsimBorder::reflect); });
    for (LpipsNet net : {LpipsNet::alex, LpipsNet::squeeze}) {
      const Lpips lpips = random_network(net);
      const std::string name = std::string("LPIPS ") + lpips_net_name(net);
      report(name + " float32 forward " + size, repeats, [&] { lpips(a, b); });
      report(name + " float32 forward+backward " + size, repeats, [&] {
        const at::Tensor p = a.clone().requires_grad_(true);
        torch::autograd::grad({lpips(p, b)}, {p});
      });
    }
    EvaluationOptions options;
    options.eight_bit_round_trip = true;
    ImageEvaluator evaluator(options, random_network(LpipsNet::alex));
    const at::Tensor mask = at::rand({h, w}) > 0.5;
    report("evaluation frame (PSNR, SSIM, LPIPS alex, tc-LPIPS) " + size, repeats,
           [&] { evaluator.add_frame(a, b, mask); });
  }

  // Two body-sized point clouds of 167,390 points (a 1.7 m tall anisotropic blob), 5 mm apart on average.
  const int64_t n = 167390;
  const at::Tensor points = at::randn({n, 3}, at::kDouble) * at::tensor({0.2, 0.5, 0.12}, at::kDouble);
  const at::Tensor moved = points + 0.005 * at::randn({n, 3}, at::kDouble);
  const at::Tensor labels = at::randint(0, 4, {n}, at::kLong);
  report("nearest neighbours (k-d tree) 167390 x 167390", repeats, [&] { nearest_neighbours(points, moved); });
  report("geometry metrics (all, face, hands) 167390 vs 167390", repeats, [&] {
    geometry_metrics({points, points, labels}, {moved, moved, labels});
  });
  return 0;
}
