// CUDA splatting benchmark on the avatar workload of issue 3: N Gaussians in a 0.5 x 1.8 x 0.3 m box 3 m in front of
// a pinhole camera at the origin (fx = fy = 1500, principal point centred), log-uniform scales 3-15 mm at 167,390
// Gaussians (times sqrt(167390 / N) otherwise, each axis times a log-uniform 0.8-1.25 factor), random unit
// quaternions, opacity 0.5-1, RGB colours, white background; float32.
//
// For each N and image size: wall time of the forward pass and of forward + backward through sfgs::render and
// torch autograd (CUDA events around the calls: 10 warm-ups, median of 50), the same through the backend entry
// points alone (no autograd, no depth division), the backend forward once more with the radix binning path forced
// (the per-tile sort's alternative), the GPU time of each pipeline stage (events around each stage, taken in
// separate runs so that they do not slow the timed ones), and the peak of the caching allocator. The forward blend
// once more per cut rule: the default (kBlendCutShare), never cut, and every run longer than a segment cut (the rule
// before issue 40). Last, one "bench-case" line per workload for scripts/bench_guard.py.
//
//   bench_splat_cuda                           the tables
//   bench_splat_cuda --profile N WIDTH HEIGHT  a few forward + backward steps of one workload, for a profiler
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDACachingAllocator.h>
#include <c10/cuda/CUDAException.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "ops/splat/cuda/diagnostics.h"
#include "ops/splat/backend.h"
#include "ops/splat/splat.h"
#include "ops/splat/constants.h"

namespace {

constexpr int kWarmups = 10;
constexpr int kRepeats = 50;
constexpr int kProfiledSteps = 3;
constexpr int64_t kReferenceCount = 167390;
constexpr double kMiB = 1024.0 * 1024.0;

struct Workload {
  int64_t count;
  int64_t width, height;
};

struct Scene {
  sfgs::Gaussians gaussians;
  at::Tensor background;
  sfgs::Camera camera;
  at::Tensor grad_image, grad_alpha;  // upstream gradients of the timed backward pass
};

at::Tensor log_uniform(std::vector<int64_t> shape, double lo, double hi, const at::TensorOptions& options) {
  return at::empty(shape, options).uniform_(std::log(lo), std::log(hi)).exp_();
}

Scene avatar_scene(const Workload& w) {
  const auto options = at::TensorOptions().device(at::kCUDA).dtype(at::kFloat);
  const int64_t n = w.count;
  Scene s;
  s.gaussians.means =
      at::rand({n, 3}, options) * at::tensor({0.5f, 1.8f, 0.3f}, options) + at::tensor({-0.25f, -0.9f, 2.85f}, options);
  const double density = std::sqrt(double(kReferenceCount) / double(n));
  s.gaussians.scales =
      log_uniform({n, 1}, 3e-3 * density, 15e-3 * density, options) * log_uniform({n, 3}, 0.8, 1.25, options);
  const at::Tensor q = at::randn({n, 4}, options);
  s.gaussians.rotations = q / q.norm(2, 1, true);
  s.gaussians.opacities = at::rand({n}, options) * 0.5f + 0.5f;
  s.gaussians.features = at::rand({n, 3}, options);
  s.background = at::ones({3}, options);
  s.camera = sfgs::Camera::looking_forward(1500.0, w.width, w.height);
  s.grad_image = at::randn({w.height, w.width, 3}, options);
  s.grad_alpha = at::randn({w.height, w.width}, options);
  for (at::Tensor* t : {&s.gaussians.means, &s.gaussians.scales, &s.gaussians.rotations, &s.gaussians.opacities,
                        &s.gaussians.features, &s.background})
    t->requires_grad_(true);
  return s;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

// Median over kRepeats runs (after kWarmups) of the milliseconds between events recorded around `run`.
template <typename Run> double time_ms(Run&& run) {
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  cudaEvent_t start, stop;
  C10_CUDA_CHECK(cudaEventCreate(&start));
  C10_CUDA_CHECK(cudaEventCreate(&stop));
  std::vector<double> times;
  for (int i = 0; i < kWarmups + kRepeats; ++i) {
    C10_CUDA_CHECK(cudaEventRecord(start, stream));
    run();
    C10_CUDA_CHECK(cudaEventRecord(stop, stream));
    C10_CUDA_CHECK(cudaEventSynchronize(stop));
    float ms = 0;
    C10_CUDA_CHECK(cudaEventElapsedTime(&ms, start, stop));
    if (i >= kWarmups) times.push_back(ms);
  }
  C10_CUDA_CHECK(cudaEventDestroy(start));
  C10_CUDA_CHECK(cudaEventDestroy(stop));
  return median(times);
}

// Records an event pair around every pipeline stage; per-stage medians over runs.
class StageTimer : public sfgs::splat::cuda_kernels::StageObserver {
 public:
  ~StageTimer() {
    for (cudaEvent_t e : pool_) cudaEventDestroy(e);
  }
  void begin(const char* stage, cudaStream_t stream) override { open_.push_back({stage, record(stream), nullptr}); }
  void end(const char* stage, cudaStream_t stream) override {
    for (auto it = open_.rbegin(); it != open_.rend(); ++it)
      if (it->name == stage && it->stop == nullptr) {
        it->stop = record(stream);
        return;
      }
  }
  // Ends one run: adds each stage's time (summed over its brackets in the run) to the samples.
  void finish_run() {
    C10_CUDA_CHECK(cudaDeviceSynchronize());
    std::map<std::string, double> run;
    for (const Interval& i : open_) {
      float ms = 0;
      C10_CUDA_CHECK(cudaEventElapsedTime(&ms, i.start, i.stop));
      run[i.name] += ms;
    }
    for (const auto& [name, ms] : run) samples_[name].push_back(ms);
    open_.clear();
    used_ = 0;
  }
  std::map<std::string, double> medians() const {
    std::map<std::string, double> out;
    for (const auto& [name, v] : samples_) out[name] = median(v);
    return out;
  }

 private:
  struct Interval {
    std::string name;
    cudaEvent_t start, stop;
  };
  cudaEvent_t record(cudaStream_t stream) {
    if (used_ == pool_.size()) {
      pool_.emplace_back();
      C10_CUDA_CHECK(cudaEventCreate(&pool_.back()));
    }
    cudaEvent_t e = pool_[used_++];
    C10_CUDA_CHECK(cudaEventRecord(e, stream));
    return e;
  }
  std::vector<cudaEvent_t> pool_;
  size_t used_ = 0;
  std::vector<Interval> open_;
  std::map<std::string, std::vector<double>> samples_;
};

const std::vector<std::string> kForwardStages = {"project", "depth sort", "emit", "tile sort", "tile ranges", "blend"};
const std::vector<std::string> kBackwardStages = {"blend backward", "project backward"};

double sum_of(const std::map<std::string, double>& stages, const std::vector<std::string>& names) {
  double total = 0;
  for (const std::string& name : names) total += stages.count(name) ? stages.at(name) : 0.0;
  return total;
}

// The backend forward and its blend stage under one cut rule of the forward blend.
struct CutTiming {
  double forward, blend;
  bool segmented;  // the blend ran the segmented kernel
};

struct Result {
  Workload workload;
  int64_t intersections;
  double op_forward, op_training, backend_forward, backend_training, backend_forward_radix, backend_training_rows;
  std::map<std::string, double> stages;
  double peak_mib, peak_above_inputs_mib;
  CutTiming cut_default, cut_never, cut_every_long_run;
};

std::vector<at::Tensor> leaves(const Scene& s) {
  return {s.gaussians.means,     s.gaussians.scales,   s.gaussians.rotations,
          s.gaussians.opacities, s.gaussians.features, s.background};
}

void train_step(const Scene& s) {
  const sfgs::RenderResult r = sfgs::render(s.gaussians, s.background, s.camera);
  torch::autograd::grad({r.image, r.alpha}, leaves(s), {s.grad_image, s.grad_alpha});
}

// Median GPU time of the blend stage over kRepeats runs of `run` (after kWarmups).
template <typename Run> double blend_stage_ms(Run&& run) {
  StageTimer timer;
  sfgs::splat::cuda_kernels::set_stage_observer(&timer);
  for (int i = 0; i < kWarmups + kRepeats; ++i) {
    run();
    timer.finish_run();
  }
  sfgs::splat::cuda_kernels::set_stage_observer(nullptr);
  const std::map<std::string, double> stages = timer.medians();
  return stages.count("blend") ? stages.at("blend") : 0.0;
}

// The backend forward under a segment length (0: never cut) and cut share; restores the defaults.
template <typename Run> CutTiming time_cut_rule(Run&& forward, int64_t segment_length, double cut_share) {
  namespace kernels = sfgs::splat::cuda_kernels;
  kernels::set_blend_segment_length(segment_length);
  kernels::set_blend_cut_share(cut_share);
  CutTiming t{time_ms(forward), blend_stage_ms(forward), false};
  t.segmented = kernels::last_blend_path() == kernels::BlendPath::kSegmented;
  kernels::set_blend_segment_length(sfgs::kBlendSegmentLength);
  kernels::set_blend_cut_share(sfgs::kBlendCutShare);
  return t;
}

Result measure(const Workload& w) {
  namespace backend = sfgs::splat;
  at::manual_seed(0);
  const Scene s = avatar_scene(w);
  const auto render = [&] { return sfgs::render(s.gaussians, s.background, s.camera); };
  const auto train = [&] { train_step(s); };

  // The backend alone: what the autograd node calls, without validation, autograd or the depth division.
  const backend::SplatInputs inputs{
      s.gaussians.means.detach(),     s.gaussians.scales.detach(),   s.gaussians.rotations.detach(), at::Tensor(),
      s.gaussians.opacities.detach(), s.gaussians.features.detach(), s.background.detach()};
  const sfgs::Camera& camera = s.camera;
  const backend::BackendSettings settings{backend::ProjectionSettings{sfgs::kLowPassVariancePx2, false}, false};
  const backend::OutputGradients grads{s.grad_image, s.grad_alpha, at::Tensor()};
  const auto backend_forward = [&] { return backend::cuda::forward(inputs, camera, settings, nullptr); };
  const auto backend_train = [&] {
    const backend::cuda::Forward f = backend_forward();
    backend::cuda::backward(inputs, camera, settings, f.outputs.image, f.context, grads);
  };

  Result r{w, 0, 0, 0, 0, 0, 0, 0, {}, 0, 0, {}, {}, {}};
  r.intersections = backend_forward().context.isect_gaussian.numel();
  r.op_forward = time_ms(render);
  r.op_training = time_ms(train);
  r.backend_forward = time_ms(backend_forward);
  r.backend_training = time_ms(backend_train);
  sfgs::splat::cuda_kernels::set_binning(sfgs::splat::cuda_kernels::Binning::kRadix);
  r.backend_forward_radix = time_ms(backend_forward);
  sfgs::splat::cuda_kernels::set_binning(sfgs::splat::cuda_kernels::Binning::kAuto);
  sfgs::splat::cuda_kernels::set_tile_order(sfgs::splat::cuda_kernels::TileOrder::kRowMajor);
  r.backend_training_rows = time_ms(backend_train);
  sfgs::splat::cuda_kernels::set_tile_order(sfgs::splat::cuda_kernels::TileOrder::kLongestFirst);
  r.cut_default = time_cut_rule(backend_forward, sfgs::kBlendSegmentLength, sfgs::kBlendCutShare);
  r.cut_never = time_cut_rule(backend_forward, 0, sfgs::kBlendCutShare);
  r.cut_every_long_run = time_cut_rule(backend_forward, sfgs::kBlendSegmentLength, 0.0);

  StageTimer timer;
  sfgs::splat::cuda_kernels::set_stage_observer(&timer);
  for (int i = 0; i < kWarmups + kRepeats; ++i) {
    train();
    timer.finish_run();
  }
  sfgs::splat::cuda_kernels::set_stage_observer(nullptr);
  r.stages = timer.medians();

  C10_CUDA_CHECK(cudaDeviceSynchronize());
  const int device = at::cuda::current_device();
  namespace allocator = c10::cuda::CUDACachingAllocator;
  // allocated_bytes is indexed by StatType, whose namespace differs between LibTorch versions; AGGREGATE comes first.
  const int64_t inputs_bytes = allocator::getDeviceStats(device).allocated_bytes.front().current;
  allocator::resetPeakStats(device);
  train();
  C10_CUDA_CHECK(cudaDeviceSynchronize());
  const int64_t peak = allocator::getDeviceStats(device).allocated_bytes.front().peak;
  r.peak_mib = double(peak) / kMiB;
  r.peak_above_inputs_mib = double(peak - inputs_bytes) / kMiB;
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  if (!torch::cuda::is_available()) {
    std::printf("bench_splat_cuda: no CUDA device\n");
    return 1;
  }
  if (argc == 5 && std::string(argv[1]) == "--profile") {
    const Workload w{std::stoll(argv[2]), std::stoll(argv[3]), std::stoll(argv[4])};
    at::manual_seed(0);
    const Scene s = avatar_scene(w);
    for (int i = 0; i < kProfiledSteps; ++i) train_step(s);
    C10_CUDA_CHECK(cudaDeviceSynchronize());
    std::printf("profiled %d forward + backward steps of N = %lld at %lld x %lld\n", kProfiledSteps, (long long)w.count,
                (long long)w.width, (long long)w.height);
    return 0;
  }
  if (argc != 1) {
    std::printf("usage: bench_splat_cuda [--profile N WIDTH HEIGHT]\n");
    return 1;
  }
  const cudaDeviceProp* prop = at::cuda::getCurrentDeviceProperties();
  std::printf("device: %s (%d SMs), median of %d runs after %d warm-ups, float32\n", prop->name,
              prop->multiProcessorCount, kRepeats, kWarmups);
  std::vector<Result> results;
  for (int64_t n : {int64_t(10000), kReferenceCount, int64_t(1000000)})
    for (const auto& [width, height] : {std::pair<int64_t, int64_t>{800, 1200}, {1080, 1920}})
      results.push_back(measure(Workload{n, width, height}));

  std::printf(
      "\nms, median. fwd, fwd+bwd: sfgs::render (+ autograd), CUDA events around the call. GPU: summed stage\n"
      "times. be: backend entry points alone (radix: forward on the radix binning path; rows: fwd+bwd with\n"
      "the tiles blended in row-major order). peak: caching-allocator peak of one fwd+bwd (MiB), -inputs:\n"
      "less what was allocated before it (scene, gradients)\n");
  std::printf("%8s %10s %9s | %8s %8s | %9s %9s | %8s %8s %8s %8s | %8s %8s\n", "N", "image", "isects", "fwd",
              "fwd GPU", "fwd+bwd", "f+b GPU", "be fwd", "be f+b", "radix", "rows", "peak", "-inputs");
  for (const Result& r : results) {
    const double forward_gpu = sum_of(r.stages, kForwardStages);
    const double training_gpu = forward_gpu + sum_of(r.stages, kBackwardStages);
    std::printf("%8lld %4lldx%-5lld %9lld | %8.3f %8.3f | %9.3f %9.3f | %8.3f %8.3f %8.3f %8.3f | %7.1fM %7.1fM\n",
                (long long)r.workload.count, (long long)r.workload.width, (long long)r.workload.height,
                (long long)r.intersections, r.op_forward, forward_gpu, r.op_training, training_gpu, r.backend_forward,
                r.backend_training, r.backend_forward_radix, r.backend_training_rows, r.peak_mib,
                r.peak_above_inputs_mib);
  }
  std::printf("\nGPU time per stage (ms, median)\n%8s %10s", "N", "image");
  std::vector<std::string> all = kForwardStages;
  all.insert(all.end(), kBackwardStages.begin(), kBackwardStages.end());
  for (const std::string& name : all) std::printf(" %16s", name.c_str());
  std::printf("\n");
  for (const Result& r : results) {
    std::printf("%8lld %4lldx%-5lld", (long long)r.workload.count, (long long)r.workload.width,
                (long long)r.workload.height);
    for (const std::string& name : all) std::printf(" %16.4f", r.stages.count(name) ? r.stages.at(name) : 0.0);
    std::printf("\n");
  }
  std::printf(
      "\nforward blend per cut rule (ms, median): be fwd and its blend stage; default: runs longer than %.1f\n"
      "times the intersections per resident block cut (* when any was, so the segmented kernel ran), uncut:\n"
      "never cut, cut-all: every run longer than %ld cut\n",
      sfgs::kBlendCutShare, long(sfgs::kBlendSegmentLength));
  std::printf("%8s %10s | %9s %9s | %9s %9s | %9s %9s\n", "N", "image", "default", "blend", "uncut", "blend", "cut-all",
              "blend");
  for (const Result& r : results) {
    std::printf("%8lld %4lldx%-5lld | %8.3f%s %9.3f | %9.3f %9.3f | %9.3f %9.3f\n", (long long)r.workload.count,
                (long long)r.workload.width, (long long)r.workload.height, r.cut_default.forward,
                r.cut_default.segmented ? "*" : " ", r.cut_default.blend, r.cut_never.forward, r.cut_never.blend,
                r.cut_every_long_run.forward, r.cut_every_long_run.blend);
  }
  std::printf("\n");
  for (const Result& r : results) {
    const double blend = r.stages.count("blend") ? r.stages.at("blend") : 0.0;
    std::printf("bench-case n=%lld image=%lldx%lld fwd_ms=%.4f fwd_bwd_ms=%.4f blend_ms=%.4f\n",
                (long long)r.workload.count, (long long)r.workload.width, (long long)r.workload.height, r.op_forward,
                r.op_training, blend);
  }
  return 0;
}
