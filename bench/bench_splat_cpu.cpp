// CPU splatting benchmark: forward and backward wall time of the reference backend on the avatar workload
// (csrc/scene/builtin_scene.h) for N in {1k, 10k, 100k} at 256x256 and 800x1200, focal scaled to the image height.
// Usage: bench_splat_cpu [repeats=5]. Prints median (min-max) milliseconds.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>
#include <torch/csrc/autograd/autograd.h>

#include "common/host_memory.h"
#include "scene/builtin_scene.h"

namespace {

struct Timing {
  double median, min, max;
};

Timing summarise(std::vector<double> ms) {
  std::sort(ms.begin(), ms.end());
  return Timing{ms[ms.size() / 2], ms.front(), ms.back()};
}

double elapsed_ms(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

int main(int argc, char** argv) {
  sfgs::reuse_freed_host_memory();
  const int repeats = argc > 1 ? std::max(1, std::atoi(argv[1])) : 5;
  if (!std::getenv("OMP_NUM_THREADS")) at::set_num_threads(int(std::max(1u, std::thread::hardware_concurrency())));
  std::printf("sfgs CPU splatting benchmark: float32, %d threads, median (min-max) of %d runs after 1 warm-up\n",
              at::get_num_threads(), repeats);
  std::printf("%9s %10s %12s %26s %26s\n", "N", "image", "bbox px/px", "forward ms", "backward ms");
  for (const auto& [width, height] : std::vector<std::pair<int64_t, int64_t>>{{256, 256}, {800, 1200}}) {
    for (int64_t n : {1000, 10000, 100000}) {
      sfgs::scene::GaussianScene s = sfgs::scene::avatar_workload(n, width, height, 1, at::kFloat);
      s.camera.fx = s.camera.fy = 1500.0 * double(height) / 1200.0;
      for (at::Tensor* t : {&s.gaussians.means, &s.gaussians.scales, &s.gaussians.rotations, &s.gaussians.opacities,
                            &s.gaussians.features})
        t->set_requires_grad(true);
      std::vector<double> fwd, bwd;
      double coverage = 0;
      for (int r = 0; r <= repeats; ++r) {
        auto start = std::chrono::steady_clock::now();
        const sfgs::RenderResult out = sfgs::render(s.gaussians, s.background, s.camera);
        const double f = elapsed_ms(start);
        start = std::chrono::steady_clock::now();
        torch::autograd::backward({out.image.sum() + out.alpha.sum()});
        const double b = elapsed_ms(start);
        if (r == 0) {
          coverage = (out.radii.to(at::kDouble).select(1, 0) * out.radii.to(at::kDouble).select(1, 1) * 4)
                         .sum()
                         .item<double>() /
                     double(width * height);
          continue;
        }
        fwd.push_back(f);
        bwd.push_back(b);
      }
      const Timing tf = summarise(fwd), tb = summarise(bwd);
      std::printf("%9lld %4lldx%-5lld %12.1f %10.2f (%6.2f-%6.2f) %10.2f (%6.2f-%6.2f)\n", (long long)n,
                  (long long)width, (long long)height, coverage, tf.median, tf.min, tf.max, tb.median, tb.min, tb.max);
    }
  }
  return 0;
}
