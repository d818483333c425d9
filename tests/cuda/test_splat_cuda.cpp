// The CUDA backend against the CPU reference: float64 parity on random scenes, float32 within stated bounds, the
// stress suite on CUDA (compared with the CPU where both are defined), and deterministic mode. CudaSanitizer.* is the
// small selection that scripts/device_check.sh runs under compute-sanitizer. Every test skips without a CUDA device.
#include <iostream>
#include <limits>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "ops/splat/cuda/diagnostics.h"
#include "splat_test_utils.h"
#include "ops/splat/constants.h"

namespace sfgs::testing {
namespace {

#define SKIP_WITHOUT_CUDA() \
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device"

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// float64 parity: relative L2 error of every output and of every gradient. Both backends evaluate the same functions
// (ops/splat/pair_math.h, ops/splat/stages.h) in the same order per pixel; what differs is the order of sums (warp
// reductions, atomics, per-tile partials) and fused multiply-adds, which cost a few ulps per operation, about 1e-13
// relative on these scenes (the CPU reference agrees with its brute-force twin to 1e-12). 1e-9 leaves four orders of
// magnitude for accumulation over deep pixels; to be confirmed on the GPU.
constexpr double kFloat64ParityBound = 1e-9;
// float32 CUDA against float64 CPU. Rounding alone stays near 1e-6 (forward) and 1e-4 (gradients); the bounds leave
// room for the discrete decisions float32 can take differently on large scenes: two Gaussians whose depths round to
// the same float swap order, a pair's alpha crossing 1/255, a pixel's transmittance crossing 1e-4.
constexpr double kFloat32ForwardBound = 1e-3;
constexpr double kFloat32GradientBound = 2e-2;

struct LossTerms {
  bool image = true, alpha = true, depth = true;
};

// Outputs and input gradients of one render, on the CPU in float64.
struct Rendered {
  at::Tensor image, alpha, depth, radii;
  std::vector<std::string> names;
  std::vector<at::Tensor> grads;
};

Rendered render_on(const TestScene& scene, at::Device device, at::ScalarType dtype, const RenderOptions& options = {},
                   LossTerms terms = {}) {
  TestScene s = scene;
  std::vector<at::Tensor> leaves;
  Rendered out;
  for (auto& [name, t] : differentiable_inputs(s)) {
    *t = t->detach().to(device, dtype).requires_grad_(true);
    leaves.push_back(*t);
    out.names.push_back(name);
  }
  const RenderResult r = render(s.gaussians, s.background, s.camera, options);
  const LossWeights w = random_weights(s.camera.height, s.camera.width, r.image.size(2), 11, dtype);
  at::Tensor loss = at::zeros({}, r.image.options());
  if (terms.image) loss = loss + (r.image * w.image.to(device)).sum();
  if (terms.alpha) loss = loss + (r.alpha * w.alpha.to(device)).sum();
  if (terms.depth) loss = loss + (r.depth * w.depth.to(device)).sum();
  const std::vector<at::Tensor> grads = torch::autograd::grad({loss}, leaves, {}, false, false, /*allow_unused=*/true);
  const auto host = [](const at::Tensor& t) { return t.detach().to(at::kCPU, at::kDouble); };
  for (size_t i = 0; i < grads.size(); ++i)
    out.grads.push_back(grads[i].defined() ? host(grads[i]) : at::zeros(leaves[i].sizes(), at::kDouble));
  out.image = host(r.image);
  out.alpha = host(r.alpha);
  out.depth = host(r.depth);
  out.radii = r.radii.to(at::kCPU);
  return out;
}

struct Bounds {
  double forward, gradient;
  bool exact_radii;
};

void expect_close(const Rendered& cuda, const Rendered& cpu, const Bounds& bounds, const std::string& label) {
  const double image = relative_error(cuda.image, cpu.image);
  const double alpha = relative_error(cuda.alpha, cpu.alpha);
  const double depth = relative_error(cuda.depth, cpu.depth);
  std::cout << "[parity] " << label << " forward: image " << image << " alpha " << alpha << " depth " << depth
            << "\n[parity] " << label << " gradients:";
  EXPECT_LE(image, bounds.forward) << label;
  EXPECT_LE(alpha, bounds.forward) << label;
  EXPECT_LE(depth, bounds.forward) << label;
  for (size_t i = 0; i < cpu.grads.size(); ++i) {
    const double e = relative_error(cuda.grads[i], cpu.grads[i]);
    std::cout << " " << cpu.names[i] << " " << e;
    EXPECT_TRUE(cuda.grads[i].isfinite().all().item<bool>()) << label << ": " << cpu.names[i];
    EXPECT_LE(e, bounds.gradient) << label << ": " << cpu.names[i];
  }
  std::cout << std::endl;
  if (bounds.exact_radii) {
    EXPECT_TRUE(at::equal(cuda.radii, cpu.radii)) << label;
  } else {
    const int64_t mismatched = (cuda.radii != cpu.radii).any(1).sum().item<int64_t>();
    EXPECT_LE(double(mismatched), 1e-3 * double(cpu.radii.size(0)) + 1) << label << ": radii of " << mismatched;
  }
}

void expect_finite(const Rendered& r, const std::string& label) {
  EXPECT_TRUE(r.image.isfinite().all().item<bool>()) << label;
  EXPECT_TRUE(r.alpha.isfinite().all().item<bool>()) << label;
  EXPECT_TRUE(r.depth.isfinite().all().item<bool>()) << label;
  for (size_t i = 0; i < r.grads.size(); ++i)
    EXPECT_TRUE(r.grads[i].isfinite().all().item<bool>()) << label << ": " << r.names[i];
}

const at::Device kCuda(at::kCUDA);

using splat::cuda_kernels::Binning;

// Forces a binning path for its lifetime.
class BinningGuard {
 public:
  explicit BinningGuard(Binning binning) { splat::cuda_kernels::set_binning(binning); }
  ~BinningGuard() { splat::cuda_kernels::set_binning(Binning::kAuto); }
  BinningGuard(const BinningGuard&) = delete;
  BinningGuard& operator=(const BinningGuard&) = delete;
};

// Sets the forward blend's segment length (0: never cut a tile's run) and cut share (0: cut every run longer than a
// segment) for its lifetime.
class BlendCutGuard {
 public:
  explicit BlendCutGuard(int64_t length, double share = 0.0) {
    splat::cuda_kernels::set_blend_segment_length(length);
    splat::cuda_kernels::set_blend_cut_share(share);
  }
  ~BlendCutGuard() {
    splat::cuda_kernels::set_blend_segment_length(kBlendSegmentLength);
    splat::cuda_kernels::set_blend_cut_share(kBlendCutShare);
  }
  BlendCutGuard(const BlendCutGuard&) = delete;
  BlendCutGuard& operator=(const BlendCutGuard&) = delete;
};

// float64 CUDA against float64 CPU, plus float32 CUDA for finiteness; returns the CUDA float64 result.
Rendered expect_parity(const TestScene& scene, const std::string& label, const RenderOptions& options = {},
                       LossTerms terms = {}) {
  const Rendered cpu = render_on(scene, at::kCPU, at::kDouble, options, terms);
  const Rendered cuda = render_on(scene, kCuda, at::kDouble, options, terms);
  expect_close(cuda, cpu, Bounds{kFloat64ParityBound, kFloat64ParityBound, true}, label);
  expect_finite(cuda, label);
  expect_finite(render_on(scene, kCuda, at::kFloat, options, terms), label + " float32");
  return cuda;
}

// ---- parity on random scenes ------------------------------------------------------------------------------------

struct ParityCase {
  const char* name;
  int64_t count, width, height, channels;
  bool covariances;
  double max_opacity;
  bool antialiased, low_pass;
};

TestScene parity_scene(const ParityCase& c, uint64_t seed) {
  SceneSpec spec;
  spec.count = c.count;
  spec.width = c.width;
  spec.height = c.height;
  spec.channels = c.channels;
  spec.covariances = c.covariances;
  spec.max_opacity = c.max_opacity;
  return random_scene(spec, seed);
}

RenderOptions parity_options(const ParityCase& c) {
  RenderOptions options;
  options.antialiased = c.antialiased;
  options.low_pass = c.low_pass;
  return options;
}

class CudaParity : public ::testing::TestWithParam<ParityCase> {};

TEST_P(CudaParity, Float64MatchesCpu) {
  SKIP_WITHOUT_CUDA();
  const ParityCase& c = GetParam();
  const TestScene scene = parity_scene(c, 101 + uint64_t(c.count));
  const Rendered cpu = render_on(scene, at::kCPU, at::kDouble, parity_options(c));
  const Rendered cuda = render_on(scene, kCuda, at::kDouble, parity_options(c));
  expect_close(cuda, cpu, Bounds{kFloat64ParityBound, kFloat64ParityBound, true}, c.name);
}

// Image sizes are not multiples of the tile size; opacities reach 1 (alpha clamp) and scenes are deep enough that
// most pixels terminate. 2048 x 2048 with 140k Gaussians needs more than 32 key bits (64-bit sort keys).
INSTANTIATE_TEST_SUITE_P(
    Scenes, CudaParity,
    ::testing::Values(ParityCase{"n1k_c1", 1000, 97, 61, 1, false, 0.7, false, true},
                      ParityCase{"n10k_c3_opaque", 10000, 250, 170, 3, false, 1.0, false, true},
                      ParityCase{"n30k_c4_covariances", 30000, 301, 203, 4, true, 0.9, false, true},
                      ParityCase{"n100k_c3_antialiased", 100000, 640, 481, 3, false, 1.0, true, true},
                      ParityCase{"n5k_c32", 5000, 123, 77, 32, false, 0.9, false, true},
                      ParityCase{"n3k_c11_sharp", 3000, 100, 90, 11, true, 1.0, false, false},
                      ParityCase{"n140k_c3_wide_keys", 140000, 2048, 2048, 3, false, 0.9, false, true}),
    [](const ::testing::TestParamInfo<ParityCase>& info) { return std::string(info.param.name); });

TEST(CudaParityLoss, ImageOnlyAndAlphaOnlyLosses) {
  SKIP_WITHOUT_CUDA();
  const TestScene scene = parity_scene(ParityCase{"", 4000, 133, 101, 3, false, 1.0, false, true}, 7);
  LossTerms image_only{true, false, false};
  LossTerms alpha_only{false, true, false};
  expect_parity(scene, "image-only loss", {}, image_only);
  expect_parity(scene, "alpha-only loss", {}, alpha_only);
}

TEST(CudaFloat32, BoundedAgainstFloat64Cpu) {
  SKIP_WITHOUT_CUDA();
  for (const ParityCase& c : {ParityCase{"float32_n10k_c3", 10000, 250, 170, 3, false, 1.0, false, true},
                              ParityCase{"float32_n100k_c3_antialiased", 100000, 640, 481, 3, false, 1.0, true, true},
                              ParityCase{"float32_n5k_c32", 5000, 123, 77, 32, false, 0.9, false, true}}) {
    const TestScene scene = parity_scene(c, 101 + uint64_t(c.count));
    const Rendered cpu = render_on(scene, at::kCPU, at::kDouble, parity_options(c));
    const Rendered cuda = render_on(scene, kCuda, at::kFloat, parity_options(c));
    expect_close(cuda, cpu, Bounds{kFloat32ForwardBound, kFloat32GradientBound, false}, c.name);
    const Rendered cpu_float = render_on(scene, at::kCPU, at::kFloat, parity_options(c));
    expect_close(cuda, cpu_float, Bounds{kFloat32ForwardBound, kFloat32GradientBound, false},
                 std::string(c.name) + " vs float32 CPU");
  }
}

// ---- deterministic mode -----------------------------------------------------------------------------------------

TEST(CudaDeterministic, BitIdenticalGradientsAcrossRuns) {
  SKIP_WITHOUT_CUDA();
  const TestScene scene = parity_scene(ParityCase{"", 30000, 301, 203, 3, false, 1.0, false, true}, 23);
  RenderOptions deterministic;
  deterministic.deterministic = true;
  for (at::ScalarType dtype : {at::kFloat, at::kDouble}) {
    const Rendered first = render_on(scene, kCuda, dtype, deterministic);
    const Rendered second = render_on(scene, kCuda, dtype, deterministic);
    EXPECT_TRUE(at::equal(first.image, second.image));
    for (size_t i = 0; i < first.grads.size(); ++i)
      EXPECT_TRUE(at::equal(first.grads[i], second.grads[i])) << first.names[i] << " in " << dtype;
    const Rendered atomic = render_on(scene, kCuda, dtype, {});
    expect_close(first, atomic, Bounds{1e-6, dtype == at::kDouble ? 1e-10 : 1e-4, true},
                 std::string("deterministic vs atomic ") + c10::toString(dtype));
  }
  const Rendered cpu = render_on(scene, at::kCPU, at::kDouble);
  expect_close(render_on(scene, kCuda, at::kDouble, deterministic), cpu,
               Bounds{kFloat64ParityBound, kFloat64ParityBound, true}, "deterministic float64 vs CPU");
}

// ---- binning paths ------------------------------------------------------------------------------------------------

void expect_identical(const Rendered& a, const Rendered& b, const std::string& label) {
  EXPECT_TRUE(at::equal(a.image, b.image)) << label;
  EXPECT_TRUE(at::equal(a.alpha, b.alpha)) << label;
  EXPECT_TRUE(at::equal(a.depth, b.depth)) << label;
  EXPECT_TRUE(at::equal(a.radii, b.radii)) << label;
  for (size_t i = 0; i < a.grads.size(); ++i)
    EXPECT_TRUE(at::equal(a.grads[i], b.grads[i])) << label << ": " << a.names[i];
}

// The per-tile sort and the radix path must give the same per-tile lists: bit-identical outputs, and bit-identical
// gradients in deterministic mode. The scenes' longest tiles (1296 and 3923 intersections) take the per-tile sort's
// size classes up to its largest in float; in double the second one exceeds the per-tile capacity (radix path).
TEST(CudaBinning, PerTileAndRadixPathsGiveIdenticalResults) {
  SKIP_WITHOUT_CUDA();
  RenderOptions deterministic;
  deterministic.deterministic = true;
  struct Case {
    ParityCase scene;
    uint64_t seed;
    bool per_tile_double;
  };
  for (const Case& c : {Case{ParityCase{"30k on 301x203", 30000, 301, 203, 3, false, 1.0, false, true}, 29, true},
                        Case{ParityCase{"12k on 96x80", 12000, 96, 80, 3, false, 1.0, false, true}, 35, false}}) {
    const TestScene scene = parity_scene(c.scene, c.seed);
    for (at::ScalarType dtype : {at::kFloat, at::kDouble}) {
      const std::string label = std::string(c.scene.name) + " " + c10::toString(dtype);
      const Rendered per_tile = render_on(scene, kCuda, dtype, deterministic);
      if (dtype == at::kFloat || c.per_tile_double) {
        EXPECT_EQ(splat::cuda_kernels::last_binning(), Binning::kAuto) << label;
      }
      const BinningGuard radix_only(Binning::kRadix);
      const Rendered radix = render_on(scene, kCuda, dtype, deterministic);
      EXPECT_EQ(splat::cuda_kernels::last_binning(), Binning::kRadix) << label;
      expect_identical(per_tile, radix, "per-tile vs radix binning, " + label);
    }
  }
}

// All Gaussians at exactly one depth, so every tile's order is decided by the Gaussian index alone.
TestScene equal_depth_scene(int64_t count, int64_t width, int64_t height, double focal, uint64_t seed) {
  SceneSpec spec;
  spec.count = count;
  spec.width = width;
  spec.height = height;
  spec.max_opacity = 0.9;
  TestScene s = random_scene(spec, seed);
  s.camera = Camera::looking_forward(focal, width, height);
  const double z = 3.0, footprint_px = 2.5;
  at::manual_seed(int64_t(seed));
  const at::Tensor u = at::rand({count, 2}, at::kDouble);
  s.gaussians.means =
      at::stack({(u.select(1, 0) - 0.5) * (double(width) * z / focal),
                 (u.select(1, 1) - 0.5) * (double(height) * z / focal), at::full({count}, z, at::kDouble)},
                1);
  s.gaussians.scales =
      at::full({count, 3}, footprint_px * z / focal, at::kDouble) * at::tensor({1.0, 1.3, 0.8}, at::kDouble);
  return s;
}

TEST(CudaBinning, EqualDepthsKeepIndexOrder) {
  SKIP_WITHOUT_CUDA();
  struct Case {
    const char* label;
    TestScene scene;
    Binning binning;  // the path float32 takes
  };
  const Case cases[] = {
      {"equal depths, per-tile sort", equal_depth_scene(3000, 97, 61, 60.0, 41), Binning::kAuto},
      {"equal depths, one tile of 5000 (radix path)", equal_depth_scene(5000, 9, 7, 40.0, 43), Binning::kRadix}};
  for (const Case& c : cases) {
    expect_parity(c.scene, c.label);
    EXPECT_EQ(splat::cuda_kernels::last_binning(), c.binning) << c.label;
    // float32 on both backends: any order other than the CPU's would move pixels by far more than rounding does.
    const Rendered cuda = render_on(c.scene, kCuda, at::kFloat);
    expect_close(cuda, render_on(c.scene, at::kCPU, at::kFloat), Bounds{1e-4, 1e-2, false},
                 std::string(c.label) + ", float32 vs float32 CPU");
  }
}

// Tiles cut into segments that separate blocks composite and a merge joins: the same image and gradients as the
// serial blend (float64 parity with the CPU, whose loop is serial), and in float32 the same as the uncut blend but
// for rounding. Lengths that are not multiples of the batch, deep opaque pixels that stop inside a segment and
// translucent ones that run through every segment.
TEST(CudaBlendSegments, CutRunsMatchTheSerialBlend) {
  SKIP_WITHOUT_CUDA();
  SceneSpec translucent;
  translucent.count = 8000;
  translucent.width = 64;
  translucent.height = 48;
  translucent.channels = 5;
  translucent.covariances = true;
  translucent.min_opacity = 0.005;
  translucent.max_opacity = 0.05;
  const std::pair<std::string, TestScene> scenes[] = {
      {"12k on 96x80", parity_scene(ParityCase{"", 12000, 96, 80, 3, false, 1.0, false, true}, 35)},
      {"8k translucent on 64x48, C=5", random_scene(translucent, 37)},
      // Opaque, so that pixels stop inside segments and hand off to the finishing kernel, with two channel chunks
      // and tiles cut by the image's edges.
      {"10k opaque on 70x45, C=5", parity_scene(ParityCase{"", 10000, 70, 45, 5, false, 1.0, false, true}, 39)}};
  for (const auto& [name, scene] : scenes) {
    const Rendered uncut = [&] {
      const BlendCutGuard never(0);
      return render_on(scene, kCuda, at::kFloat);
    }();
    for (int64_t length : {100, 700}) {
      const BlendCutGuard cut(length);
      const std::string label = name + ", segments of " + std::to_string(length);
      expect_parity(scene, label);
      expect_close(render_on(scene, kCuda, at::kFloat), uncut, Bounds{1e-6, 1e-4, true}, label + ", float32 vs uncut");
    }
  }
}

// A sparse field whose runs all fit a segment and, with pile > 0, that many more small Gaussians piled onto a few of
// its tiles (an avatar's face on a generic scene): runs far beyond the pass's share of intersections per block.
TestScene field_with_pile(int64_t pile) {
  SceneSpec field;
  field.count = 600;
  field.width = 256;
  field.height = 192;
  field.min_footprint_px = 0.8;
  field.max_footprint_px = 2.0;
  TestScene s = random_scene(field, 41);
  if (pile == 0) return s;
  field.count = pile;
  const Gaussians p = random_scene(field, 43).gaussians;  // the same camera: it depends on the image size alone
  const at::Tensor centre = p.means[0];
  Gaussians& g = s.gaussians;
  g.means = at::cat({g.means, centre + (p.means - centre) * 0.03});
  g.scales = at::cat({g.scales, p.scales});
  g.rotations = at::cat({g.rotations, p.rotations});
  g.opacities = at::cat({g.opacities, p.opacities});
  g.features = at::cat({g.features, p.features});
  return s;
}

TEST(CudaBlendSegments, OnlyRunsBeyondTheShareAreCut) {
  SKIP_WITHOUT_CUDA();
  namespace kernels = splat::cuda_kernels;
  const std::pair<int64_t, kernels::BlendPath> cases[] = {{0, kernels::BlendPath::kWholeTiles},
                                                          {3000, kernels::BlendPath::kSegmented}};
  for (const auto& [pile, path] : cases) {
    const TestScene scene = field_with_pile(pile);
    const std::string label = pile == 0 ? "short runs only" : "short runs and a pile of " + std::to_string(pile);
    expect_parity(scene, label);
    const Rendered eager = render_on(scene, kCuda, at::kFloat);
    EXPECT_EQ(kernels::last_blend_path(), path) << label;
    const Rendered uncut = [&] {
      const BlendCutGuard never(0);
      return render_on(scene, kCuda, at::kFloat);
    }();
    expect_close(eager, uncut, Bounds{1e-6, 1e-4, true}, label + ", float32 vs uncut");
    // A budget hides the pass's counts from the host: the segmented kernel runs and its plan on the device cuts
    // what the eager pass cut, so the image is the eager one.
    const at::Tensor counts = at::zeros({BinningBudget::kCounts}, at::TensorOptions(kCuda).dtype(at::kLong));
    const BinningBudget budget{1 << 22, 1 << 22, counts};
    RenderOptions budgeted_options;
    budgeted_options.budget = &budget;
    const Rendered budgeted = render_on(scene, kCuda, at::kFloat, budgeted_options);
    EXPECT_EQ(kernels::last_blend_path(), kernels::BlendPath::kSegmented) << label;
    EXPECT_TRUE(budgeted.image.equal(eager.image)) << label;
    EXPECT_TRUE(budgeted.alpha.equal(eager.alpha)) << label;
  }
}

// ---- stress (mirrors tests/cpp/test_splat_stress.cpp on CUDA) --------------------------------------------------

TestScene base_scene(int64_t count = 8) {
  SceneSpec spec;
  spec.count = count;
  return random_scene(spec, 17);
}

void set_row(at::Tensor& t, int64_t row, std::vector<double> values) {
  t.select(0, row).copy_(at::tensor(values, t.options()));
}

bool visible(const Rendered& r, int64_t i) { return (r.radii[i] > 0).all().item<bool>(); }

TEST(CudaStress, ZeroTinyAndHugeScales) {
  SKIP_WITHOUT_CUDA();
  for (double scale : {0.0, 1e-9}) {
    TestScene s = base_scene(64);
    set_row(s.gaussians.scales, 0, {scale, scale, scale});
    set_row(s.gaussians.scales, 1, {scale, 0.01, 0.01});
    const Rendered r = expect_parity(s, "scale " + std::to_string(scale));
    EXPECT_TRUE(visible(r, 0)) << "scale " << scale;
  }
  // Gaussian 1 becomes a needle with axes 1e6 and 0.01 (covariance condition number 1e16): its projected determinant
  // a c - b^2 cancels to rounding noise in float64 on either backend, so both agree only to that noise.
  TestScene huge = base_scene(64);
  set_row(huge.gaussians.scales, 0, {1e6, 1e6, 1e6});
  set_row(huge.gaussians.scales, 1, {1e6, 0.01, 0.01});
  const Rendered cpu = render_on(huge, at::kCPU, at::kDouble);
  const Rendered cuda = render_on(huge, kCuda, at::kDouble);
  expect_close(cuda, cpu, Bounds{1e-3, 5e-2, true}, "scale 1e6 (conditioning-limited)");
  expect_finite(cuda, "scale 1e6");
  expect_finite(render_on(huge, kCuda, at::kFloat), "scale 1e6 float32");
  EXPECT_TRUE(visible(cuda, 0));
  EXPECT_TRUE(visible(cuda, 1));

  TestScene s = base_scene(64);
  set_row(s.gaussians.scales, 0, {0.0, 0.0, 0.0});
  RenderOptions sharp;
  sharp.low_pass = false;
  const Rendered r = expect_parity(s, "point without low-pass", sharp);
  EXPECT_FALSE(visible(r, 0));
  EXPECT_EQ(r.grads[0][0].abs().sum().item<double>(), 0.0);
}

TEST(CudaStress, SingularAndIndefiniteCovariances) {
  SKIP_WITHOUT_CUDA();
  SceneSpec spec;
  spec.count = 64;
  spec.covariances = true;
  TestScene s = random_scene(spec, 5);
  set_row(s.gaussians.covariances, 0, {1e-4, 0, 0, 0, 0, 0});
  set_row(s.gaussians.covariances, 1, {1e-4, 0, 0, 1e-4, 0, 0});
  set_row(s.gaussians.covariances, 2, {1e-4, 2e-4, 0, 1e-4, 0, 1e-4});
  set_row(s.gaussians.covariances, 3, {-1e-4, 0, 0, 1e-4, 0, 1e-4});
  set_row(s.gaussians.covariances, 4, {0, 0, 0, 0, 0, 0});
  const Rendered r = expect_parity(s, "singular covariances");
  const std::vector<bool> expected{true, true, false, false, true};
  for (int64_t i = 0; i < 5; ++i) EXPECT_EQ(visible(r, i), expected[i]) << "Gaussian " << i;
}

TEST(CudaStress, MeansBehindOnNearPlaneAndFarAway) {
  SKIP_WITHOUT_CUDA();
  TestScene s = base_scene(64);
  s.camera.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  s.camera.near_plane = 0.1;
  set_row(s.gaussians.means, 0, {0.0, 0.0, -1.0});
  set_row(s.gaussians.means, 1, {0.0, 0.0, 0.1});
  set_row(s.gaussians.means, 2, {0.0, 0.0, 0.0});
  set_row(s.gaussians.means, 3, {0.0, 0.0, 1e8});
  set_row(s.gaussians.means, 4, {1e3, 0.0, 1.0});
  set_row(s.gaussians.means, 5, {0.0, 0.0, 2e10});
  const Rendered r = expect_parity(s, "means behind, on the near plane, far away");
  const std::vector<bool> expected{false, true, false, true, false, false};
  for (int64_t i = 0; i < 6; ++i) EXPECT_EQ(visible(r, i), expected[i]) << "Gaussian " << i;
}

TEST(CudaStress, OpacityExactlyZeroAndOne) {
  SKIP_WITHOUT_CUDA();
  TestScene s = base_scene(64);
  s.gaussians.opacities[0] = 0.0;
  s.gaussians.opacities[1] = 1.0;
  s.gaussians.opacities[2] = 1.0;
  const Rendered r = expect_parity(s, "opacity 0 and 1");
  EXPECT_FALSE(visible(r, 0));
  EXPECT_TRUE(visible(r, 1));
}

TEST(CudaStress, NonFiniteValuesCullOnlyTheirGaussian) {
  SKIP_WITHOUT_CUDA();
  for (double bad : {kNaN, kInf, -kInf}) {
    for (const std::string field : {"means", "scales", "rotations", "features"}) {
      TestScene s = base_scene(64);
      at::Tensor& t = field == "means"       ? s.gaussians.means
                      : field == "scales"    ? s.gaussians.scales
                      : field == "rotations" ? s.gaussians.rotations
                                             : s.gaussians.features;
      t.view({-1})[t.numel() / t.size(0) * 3] = bad;
      const Rendered r = expect_parity(s, field + " = " + std::to_string(bad));
      EXPECT_FALSE(visible(r, 3)) << field << " = " << bad;
    }
  }
  SceneSpec spec;
  spec.count = 64;
  spec.covariances = true;
  TestScene s = random_scene(spec, 5);
  s.gaussians.covariances[2][1] = kNaN;
  EXPECT_FALSE(visible(expect_parity(s, "NaN covariance"), 2));
  TestScene q = base_scene(64);
  set_row(q.gaussians.rotations, 0, {0, 0, 0, 0});
  EXPECT_FALSE(visible(expect_parity(q, "zero quaternion"), 0));
}

// Opacities outside [0, 1] or not finite: the projection kernel counts them into BinStats, and the forward pass
// reports them right after its one read of BinStats, with the CPU's message.
TEST(CudaStress, OpacitiesOutsideTheUnitIntervalAreErrors) {
  SKIP_WITHOUT_CUDA();
  SceneSpec spec;
  spec.count = 4000;
  TestScene s = random_scene(spec, 2);
  s.gaussians.opacities[17] = 5.0;
  s.gaussians.opacities[100] = kNaN;
  s.gaussians.opacities[3999] = -0.5;
  const std::string expected =
      "sfgs::render: opacities must be finite and in [0, 1]; 3 of 4000 are not (first: index 17, value 5)";
  for (at::ScalarType dtype : {at::kFloat, at::kDouble})
    for (at::Device device : {at::Device(at::kCPU), kCuda}) {
      TestScene d = s;
      for (auto& [name, t] : differentiable_inputs(d)) *t = t->to(device, dtype);
      try {
        render(d.gaussians, d.background, d.camera);
        ADD_FAILURE() << "expected an error on " << device << " in " << dtype;
      } catch (const c10::Error& e) {
        EXPECT_NE(std::string(e.what_without_backtrace()).find(expected), std::string::npos)
            << e.what_without_backtrace();
      }
    }
  // The stream is usable afterwards, and opacities of exactly 0 and 1 are fine.
  s.gaussians.opacities.fill_(1.0);
  s.gaussians.opacities[5] = 0.0;
  expect_parity(s, "opacities 0 and 1 after an error");
}

TEST(CudaStress, ThousandsOfGaussiansOnOnePixel) {
  SKIP_WITHOUT_CUDA();
  const int64_t n = 5000;
  TestScene s = base_scene(n);
  s.camera = Camera::looking_forward(40.0, 9, 7);
  s.gaussians.means = at::tensor({0.0, 0.0, 2.0}, at::kDouble).repeat({n, 1}) + 1e-3 * at::randn({n, 3}, at::kDouble);
  // Anisotropic, so that rotation gradients are not rounding noise around zero on both sides.
  s.gaussians.scales = at::full({n, 3}, 0.002, at::kDouble) * at::tensor({1.0, 1.4, 0.7}, at::kDouble);
  const Rendered r = expect_parity(s, "5000 Gaussians on one pixel");
  EXPECT_NEAR(r.alpha[3][4].item<double>(), 1.0 - kMinTransmittance, 3e-4);
  EXPECT_EQ(splat::cuda_kernels::last_binning(), Binning::kRadix) << "one tile longer than the per-tile sort holds";
}

TEST(CudaStress, OneByOneAndHugeImages) {
  SKIP_WITHOUT_CUDA();
  TestScene s = base_scene();
  s.camera = Camera::looking_forward(1.0, 1, 1);
  set_row(s.gaussians.means, 0, {0.0, 0.0, 3.0});
  const Rendered one = expect_parity(s, "1x1 image");
  EXPECT_GT(one.alpha.item<double>(), 0.0);

  TestScene big = base_scene(200);
  big.camera = Camera::looking_forward(4000.0, 4096, 4096);
  big.gaussians.means = big.gaussians.means * at::tensor({1.0, 1.0, 0.0}) + at::tensor({0.0, 0.0, 3.0});
  big.gaussians.scales = at::full({200, 3}, 0.004, at::kDouble) * at::tensor({1.0, 1.4, 0.7}, at::kDouble);
  const Rendered r = expect_parity(big, "4096x4096 image");
  EXPECT_EQ(r.image.sizes(), at::IntArrayRef({4096, 4096, 3}));
  EXPECT_GT(r.alpha.max().item<double>(), 0.5);
}

TEST(CudaStress, NoGaussians) {
  SKIP_WITHOUT_CUDA();
  TestScene s = base_scene(0);
  const Rendered r = expect_parity(s, "N = 0");
  EXPECT_TRUE(at::allclose(r.image, s.background.expand({s.camera.height, s.camera.width, 3})));
  EXPECT_EQ(r.alpha.abs().sum().item<double>(), 0.0);
}

// ---- the small selection run under compute-sanitizer ------------------------------------------------------------

TEST(CudaSanitizer, SmallScenes) {
  SKIP_WITHOUT_CUDA();
  RenderOptions deterministic;
  deterministic.deterministic = true;
  for (int64_t channels : {3, 5}) {
    const TestScene scene = parity_scene(ParityCase{"", 300, 45, 38, channels, channels == 5, 1.0, false, true}, 3);
    const std::string label = "sanitizer C=" + std::to_string(channels);
    expect_parity(scene, label);
    expect_parity(scene, label + " deterministic", deterministic);
    const BinningGuard radix_only(Binning::kRadix);
    expect_parity(scene, label + " radix binning", deterministic);
    const BlendCutGuard cut(50);
    expect_parity(scene, label + " blend segments of 50", deterministic);
  }
  expect_parity(base_scene(0), "sanitizer N = 0");
}

}  // namespace
}  // namespace sfgs::testing
