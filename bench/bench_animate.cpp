// Animation benchmark: pose -> image of an avatar through animate::Animator (csrc/animate/animator.h), at several
// image sizes. Per size: the median frame time and frames/s of graph frames (one CUDA graph replay each) and of eager
// frames, and the per-stage split of an eager frame (StageClock, device synchronised per stage).
// CUDA: graph frames are also timed per back-facing cull cosine (--cull-cosines, default 0.3,0.5,0.7,1; 1 culls
// nothing), each with the lowest PSNR of its frames against the exact render (the LibTorch float32 structure
// offset, nothing culled): the cull's run time against its error. And per forward-blend segment length
// (--blend-segments, default 0,128,192,256,384,512; 0 never cuts a tile's run; csrc/ops/splat/cuda/blend_forward.cu)
// and per cut share (--blend-cut-shares, default 0,0.5,1,1.5,2,4: runs longer than that many times the intersections
// per resident block are cut; 0 cuts every run longer than a segment; kBlendCutShare) the median graph frame and the
// largest difference to the uncut image. Per size, the tile runs of the first pose (print_tile_runs: what the blend's
// work is made of). And batches of --batch frames (default 8) through animate::BatchAnimator per lane count
// (--batch-lanes, default 1,2,4,8): what rendering frames side by side on several streams gains.
// Usage: bench_animate [--device cpu|cuda] [--shared DIR] [--run DIR] [--levels L] [--sizes 800x1200,540x960]
//                      [--frames N] [--cull-cosines C,...] [--blend-segments L,...] [--blend-cut-shares S,...]
//                      [--batch B] [--batch-lanes L,...] [--profile 1] [--time T]
//   --time T: replayed training frames (with the time branch and, for a trained avatar, the observation prior) at
//   times from T on, each frame its own, instead of new-motion frames; the cull and blend tables stay new-motion.
//   --shared DIR: the Anny stand-in body of DIR/bodies (with MANO hands and face ids) instead of the procedural body.
//   --run DIR: a trained avatar (a run folder of `sfgs train`) instead of an untrained one; --shared, --levels unused.
//   --profile 1: for Nsight Compute (`ncu --profile-from-start off --nvtx`): after the warm-up, one eager frame and
//   one graph frame of the first size are profiled (replayed frames with --time), their stages as NVTX ranges
//   (profiled_range.h); no timing.
// Without --run the avatar is untrained (same network work per frame as a trained one of its configuration; the
// splatting work differs); it shows the motion of a smooth sweep between two random poses, framed by a camera in
// front of it.
#include <algorithm>
#include <optional>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>
#include <torch/cuda.h>

#include "animate/animator.h"
#include "animate/batch_animator.h"
#include "body/mesh.h"
#include "body/skeleton.h"
#include "common/host_memory.h"
#ifdef SFGS_BENCH_CUDA_KERNELS
#include "ops/splat/constants.h"
#include "ops/splat/cuda/diagnostics.h"
#endif
#include "metrics/image_metrics.h"
#include "model/observation_prior.h"
#include "ops/splat/backend.h"
#include "ops/splat/validation.h"
#include "train/run_folder.h"
#include "flags.h"
#include "profiled_range.h"
#include "stage_clock.h"

namespace {

using sfgs::body::SmplxPose;

constexpr double kReplayTimeStep = 0.01;  // between the times of consecutive replayed frames (--time)

struct Arguments {
  std::string device = "cuda";
  std::string shared;
  std::string run;
  int64_t levels = 2;
  std::vector<std::pair<int64_t, int64_t>> sizes{{800, 1200}, {540, 960}};
  int frames = 200;
  bool profile = false;
  std::optional<double> time;  // replayed frames: times from this on (each frame its own), else new-motion frames
  std::vector<double> cull_cosines{0.3, 0.5, 0.7, 1.0};
  std::vector<int64_t> blend_segments{0, 128, 192, 256, 384, 512};
  std::vector<double> blend_cut_shares{0.0, 0.5, 1.0, 1.5, 2.0, 4.0};
  int64_t batch = 8;                             // frames of one BatchAnimator call
  std::vector<int64_t> batch_lanes{1, 2, 4, 8};  // Animators on streams of their own
};

[[noreturn]] void usage() {
  std::fprintf(stderr,
               "usage: bench_animate [--device cpu|cuda] [--shared DIR] [--run DIR] [--levels L] "
               "[--sizes WxH,...] [--frames N] [--cull-cosines C,...] [--blend-segments L,...] "
               "[--blend-cut-shares S,...] [--batch B] [--batch-lanes L,...] [--profile 1]\n");
  std::exit(2);
}

double real(const std::string& item) { return std::atof(item.c_str()); }
int64_t integer(const std::string& item) { return std::atol(item.c_str()); }

Arguments parse(int argc, char** argv) {
  using sfgs::bench::listed;
  Arguments a;
  sfgs::bench::parse_flags(argc, argv, usage, [&](const std::string& flag, const std::string& value) {
    if (flag == "--device")
      a.device = value;
    else if (flag == "--shared")
      a.shared = value;
    else if (flag == "--run")
      a.run = value;
    else if (flag == "--levels")
      a.levels = std::max(0, std::atoi(value.c_str()));
    else if (flag == "--frames")
      a.frames = std::max(1, std::atoi(value.c_str()));
    else if (flag == "--profile")
      a.profile = value == "1";
    else if (flag == "--time")
      a.time = std::clamp(std::atof(value.c_str()), -1.0, 1.0);
    else if (flag == "--cull-cosines")
      a.cull_cosines = listed<double>(value, usage, real);
    else if (flag == "--blend-segments")
      a.blend_segments = listed<int64_t>(value, usage, integer);
    else if (flag == "--blend-cut-shares")
      a.blend_cut_shares = listed<double>(value, usage, real);
    else if (flag == "--batch")
      a.batch = std::max(1L, std::atol(value.c_str()));
    else if (flag == "--batch-lanes")
      a.batch_lanes =
          listed<int64_t>(value, usage, [](const std::string& item) { return std::max<int64_t>(1, integer(item)); });
    else if (flag == "--sizes")
      a.sizes = listed<std::pair<int64_t, int64_t>>(value, usage, [](const std::string& item) {
        long w = 0, h = 0;
        if (std::sscanf(item.c_str(), "%ldx%ld", &w, &h) != 2 || w <= 0 || h <= 0) usage();
        return std::pair<int64_t, int64_t>(w, h);
      });
    else
      return false;
    return true;
  });
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
  c.world_to_camera = {1, 0, 0,  -centre[0].item<double>(),           0, -1, 0, centre[1].item<double>(),
                       0, 0, -1, centre[2].item<double>() + distance, 0, 0,  0, 1};
  return c;
}

// Frame k's time from `first` on (each frame another time, so the eager path's cache of one time never serves it).
std::optional<double> frame_time(std::optional<double> first, int k) {
  if (!first) return std::nullopt;
  return std::clamp(*first + kReplayTimeStep * double(k % 100), -1.0, 1.0);
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Milliseconds of each of `frames` frames of the sweep, the device synchronised after each (the Animator's graph
// frames end with a wait for the image anyway).
std::vector<double> time_frames(sfgs::animate::Animator& animator, const SmplxPose& a, const SmplxPose& b, int frames,
                                bool cuda, std::optional<double> time = std::nullopt) {
  std::vector<double> ms;
  for (int k = 0; k < frames; ++k) {
    const SmplxPose pose = blend(a, b, double(k) / double(frames));
    const auto start = std::chrono::steady_clock::now();
    animator.render(pose, frame_time(time, k));
    if (cuda) torch::cuda::synchronize();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  }
  return ms;
}

// A batch of frames through animate::BatchAnimator per lane count (1: one graph replay after another): the median
// time of a whole batch over a sweep of batches, per frame, and the largest difference to the one-lane batch.
void print_batch_table(sfgs::model::Avatar& avatar, const sfgs::Camera& camera, const at::Tensor& background,
                       const SmplxPose& a, const SmplxPose& b, const Arguments& args) {
  std::printf("  batches of %ld frames (new motion): lanes | ms a batch | ms a frame | frames/s | largest difference\n",
              long(args.batch));
  at::Tensor first;
  const int rounds = std::max(5, args.frames / int(args.batch));
  for (int64_t lanes : args.batch_lanes) {
    sfgs::animate::BatchAnimator batch(avatar, background, {}, lanes);
    std::vector<double> ms;
    at::Tensor image;
    for (int r = 0; r < rounds + 2; ++r) {
      std::vector<sfgs::animate::BatchFrame> frames;
      for (int64_t k = 0; k < args.batch; ++k)
        frames.push_back({camera, blend(a, b, double(r * args.batch + k) / double(rounds * args.batch)), std::nullopt});
      const auto start = std::chrono::steady_clock::now();
      image = batch.render(frames).image;
      torch::cuda::synchronize();
      if (r >= 2)
        ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
    }
    if (!first.defined()) first = image;
    const double m = median(ms);
    std::printf("    %ld | %.3f | %.3f | %.0f | %.2e\n", long(lanes), m, m / double(args.batch),
                1000.0 * double(args.batch) / m, (image - first).abs().max().item<double>());
  }
}

// Run time against error of the back-facing cull: per cosine, the median graph frame, its intersections, and the
// lowest PSNR over a few poses of its frames against the exact render (the LibTorch float32 structure offset,
// nothing culled). The cache is cleared for the exact render and kept again after.
void print_culling_table(sfgs::model::Avatar& avatar, const sfgs::Camera& camera, const at::Tensor& background,
                         const SmplxPose& a, const SmplxPose& b, const Arguments& args) {
  const int checks = 5;
  std::vector<SmplxPose> poses;
  for (int k = 0; k < checks; ++k) poses.push_back(blend(a, b, double(k) / (checks - 1)));
  std::vector<double> frame_ms;
  std::vector<int64_t> intersections;
  std::vector<std::vector<at::Tensor>> images;
  for (double cosine : args.cull_cosines) {
    sfgs::animate::AnimatorOptions options;
    options.back_facing_cosine = cosine;
    sfgs::animate::Animator animator(avatar, camera, background, options);
    time_frames(animator, a, b, 3, true);  // captures
    frame_ms.push_back(median(time_frames(animator, a, b, args.frames, true)));
    intersections.push_back(animator.stats().intersections);
    images.emplace_back();
    for (const SmplxPose& pose : poses) images.back().push_back(animator.render(pose).clone());
  }
  std::vector<double> lowest(args.cull_cosines.size(), 1e9);
  {
    at::NoGradGuard no_grad;
    avatar->clear_cache();
    for (int k = 0; k < checks; ++k) {
      const at::Tensor exact = sfgs::render(sfgs::model::to_gaussians(avatar->forward(poses[size_t(k)], std::nullopt)),
                                            background.to(images[0][0].device()), camera)
                                   .image;
      for (size_t c = 0; c < lowest.size(); ++c)
        lowest[c] = std::min(lowest[c], sfgs::metrics::psnr(images[c][size_t(k)], exact).item<double>());
    }
    avatar->cache_static_features();
  }
  std::printf(
      "  back-facing cull: cosine | graph frame ms | intersections | PSNR vs exact render (lowest of %d "
      "poses; cosine >= 1: nothing culled, the fused MLP alone)\n",
      checks);
  for (size_t c = 0; c < lowest.size(); ++c)
    std::printf("    %.2f | %.3f | %ld | %.1f dB\n", args.cull_cosines[c], frame_ms[c], long(intersections[c]),
                lowest[c]);
}

// Run time of the forward blend's segment lengths (the first, usually 0 = never cut, is the reference image).
void print_blend_segment_table(sfgs::model::Avatar& avatar, const sfgs::Camera& camera, const at::Tensor& background,
                               const SmplxPose& a, const SmplxPose& b, const Arguments& args) {
#ifdef SFGS_BENCH_CUDA_KERNELS
  at::Tensor reference;
  std::printf(
      "  forward blend segments (cut share %.1f): length (0: uncut) | graph frame ms | largest difference "
      "to the first\n",
      sfgs::kBlendCutShare);
  for (int64_t length : args.blend_segments) {
    sfgs::splat::cuda_kernels::set_blend_segment_length(length);
    sfgs::animate::Animator animator(avatar, camera, background);
    time_frames(animator, a, b, 3, true);  // captures
    const double ms = median(time_frames(animator, a, b, args.frames, true));
    const at::Tensor image = animator.render(a).clone();
    if (!reference.defined()) reference = image;
    std::printf("    %ld | %.3f | %.2e\n", long(length), ms, (image - reference).abs().max().item<double>());
  }
  sfgs::splat::cuda_kernels::set_blend_segment_length(sfgs::kBlendSegmentLength);
  std::printf(
      "  forward blend cut share (segments of %ld; 0: every longer run cut) | graph frame ms | largest "
      "difference to the first length's image\n",
      long(sfgs::kBlendSegmentLength));
  for (double share : args.blend_cut_shares) {
    sfgs::splat::cuda_kernels::set_blend_cut_share(share);
    sfgs::animate::Animator animator(avatar, camera, background);
    time_frames(animator, a, b, 3, true);  // captures
    const double ms = median(time_frames(animator, a, b, args.frames, true));
    const at::Tensor image = animator.render(a).clone();
    std::printf("    %.2f | %.3f | %.2e\n", share, ms,
                reference.defined() ? (image - reference).abs().max().item<double>() : 0.0);
  }
  sfgs::splat::cuda_kernels::set_blend_cut_share(sfgs::kBlendCutShare);
#else
  (void)avatar, (void)camera, (void)background, (void)a, (void)b, (void)args;
#endif
}

// The CUDA blends' pixel block of a warp (csrc/ops/splat/cuda/blend_common.cuh): a Gaussian is evaluated by a warp
// only when it can reach one of the warp's pixels.
constexpr int kWarpBlockWidth = 8, kWarpBlockHeight = 4;

// What the blend's work is made of, from the CPU reference's pass over one frame of the pose (the avatar's Gaussians
// as its forward gives them): the tiles' run lengths (a run is one tile's depth-ordered list; the longest set how long
// a blend lasts), how far into its run a tile's pixels composite before their transmittance runs out, and the warp
// evaluations ("hits": a Gaussian of a run against one warp's pixel block that it can reach) up to that point.
void print_tile_runs(sfgs::model::Avatar& avatar, const sfgs::Camera& camera, const SmplxPose& pose) {
  at::NoGradGuard no_grad;
  const sfgs::Gaussians g = sfgs::model::to_gaussians(avatar->forward(pose, std::nullopt));
  const auto host = [](const at::Tensor& t) {
    return t.defined() ? t.detach().to(at::kCPU, at::kFloat).contiguous() : at::Tensor();
  };
  const sfgs::splat::SplatInputs inputs{host(g.means),
                                        host(g.scales),
                                        host(g.rotations),
                                        host(g.covariances),
                                        host(g.opacities).reshape({-1}),
                                        host(g.features),
                                        at::ones({g.features.size(1)})};
  const sfgs::splat::BackendSettings settings{{sfgs::kLowPassVariancePx2, false}, false};
  const sfgs::splat::cpu::Forward pass = sfgs::splat::cpu::forward(inputs, camera, settings);
  const int width = int(camera.width), height = int(camera.height);
  const int tiles_x = (width + sfgs::kTileSize - 1) / sfgs::kTileSize;
  const int64_t tiles = pass.context.tile_offsets.size(0) - 1;
  const auto* offset = pass.context.tile_offsets.data_ptr<int64_t>();
  const auto* last = pass.context.contributors.data_ptr<int32_t>();
  const auto* projected = pass.context.projected.data_ptr<float>();
  const auto* order = pass.context.tile_order.data_ptr<int64_t>();
  const auto* gaussian_of = pass.context.isect_gaussian.data_ptr<int64_t>();
  struct Run {
    int64_t tile, length, composited, hits;
  };
  std::vector<Run> runs;
  for (int64_t t = 0; t < tiles; ++t) {
    Run run{t, offset[t + 1] - offset[t], 0, 0};
    if (run.length == 0) continue;
    const int x0 = int(t % tiles_x) * sfgs::kTileSize, y0 = int(t / tiles_x) * sfgs::kTileSize;
    const int x1 = std::min(x0 + sfgs::kTileSize, width), y1 = std::min(y0 + sfgs::kTileSize, height);
    for (int y = y0; y < y1; ++y)
      for (int x = x0; x < x1; ++x) run.composited = std::max<int64_t>(run.composited, last[int64_t(y) * width + x]);
    for (int64_t k = offset[t]; k < offset[t] + run.composited; ++k) {
      const auto gaussian =
          sfgs::splat::load_projected(projected + gaussian_of[order[k]] * sfgs::splat::kProjectedWidth);
      for (int by = y0; by < y1; by += kWarpBlockHeight)
        for (int bx = x0; bx < x1; bx += kWarpBlockWidth)
          run.hits += sfgs::splat::pixel_block_touched(gaussian, bx, by, std::min(bx + kWarpBlockWidth, x1) - 1,
                                                       std::min(by + kWarpBlockHeight, y1) - 1);
    }
    runs.push_back(run);
  }
  if (runs.empty()) {
    std::printf("  tile runs: none (nothing of the avatar is in view)\n");
    return;
  }
  std::sort(runs.begin(), runs.end(), [](const Run& x, const Run& y) { return x.length > y.length; });
  const int64_t intersections = offset[tiles];
  int64_t hits = 0;
  for (const Run& r : runs) hits += r.hits;
  const auto percentile = [&](double p) { return runs[size_t(double(runs.size() - 1) * (1 - p))].length; };
  std::printf(
      "  tile runs (CPU reference pass of the first pose): %ld of %ld tiles hold one; length median %ld, 90th %ld, "
      "99th %ld, longest %ld; %.2f warp hits an intersection\n",
      long(runs.size()), long(tiles), long(percentile(0.5)), long(percentile(0.9)), long(percentile(0.99)),
      long(runs.front().length), double(hits) / double(intersections));
  for (int64_t cut : {256, 640, 2048}) {
    int64_t count = 0, length = 0, composited = 0;
    for (const Run& r : runs)
      if (r.length > cut) ++count, length += r.length, composited += r.composited;
    std::printf("    runs > %4ld: %4ld tiles, %5.1f %% of the intersections, %5.1f %% of their length composited\n",
                long(cut), long(count), 100.0 * double(length) / double(intersections),
                length ? 100.0 * double(composited) / double(length) : 0.0);
  }
  std::printf("    longest runs (tile x,y: length, composited, warp hits):");
  for (size_t k = 0; k < std::min<size_t>(6, runs.size()); ++k)
    std::printf(" %ld,%ld: %ld, %ld, %ld;", long(runs[k].tile % tiles_x), long(runs[k].tile / tiles_x),
                long(runs[k].length), long(runs[k].composited), long(runs[k].hits));
  std::printf("\n");
}

}  // namespace

// A trained avatar's observation prior (model/observation_prior.h): how much of the body is well observed, the rings
// its propagation fills the rest in, and the propagation's time over the colour logits (eager, the device
// synchronised): what a replayed frame pays for it.
void print_observation_prior(sfgs::model::Avatar& avatar, bool cuda) {
  const at::Tensor& observed = avatar->observation();
  if (!observed.defined()) return;
  const int64_t n = avatar->gaussian_count();
  const sfgs::body::VertexNeighbours neighbours = sfgs::body::vertex_neighbours(avatar->faces().cpu(), n);
  const at::Tensor confidence = sfgs::model::observation_confidence(observed);
  const sfgs::model::PropagationPlan plan = sfgs::model::plan_propagation(confidence, neighbours, at::kFloat);
  const at::Tensor values = at::rand({n, 3}, confidence.options());
  std::vector<double> ms;
  for (int k = 0; k < 23; ++k) {
    const auto start = std::chrono::steady_clock::now();
    sfgs::model::propagate_from_observed(values, plan);
    if (cuda) torch::cuda::synchronize();
    const double elapsed = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    if (k >= 3) ms.push_back(elapsed);
  }
  std::printf(
      "  observation prior: %ld of %ld points well observed; %ld rings fill %ld points (the widest %ld); "
      "propagation %.3f ms (eager, median of 20)\n",
      long((confidence >= 1).sum().item<int64_t>()), long(n), long(plan.ring_count()), long(plan.filled_count()),
      long(plan.widest_ring()), median(ms));
}

int main(int argc, char** argv) {
  sfgs::reuse_freed_host_memory();
  const Arguments args = parse(argc, argv);
  const bool cuda = args.device == "cuda";
  if (!cuda && args.device != "cpu") usage();
  if (cuda && !torch::cuda::is_available()) {
    std::fprintf(stderr, "bench_animate: --device cuda, but this LibTorch sees no CUDA device\n");
    return 1;
  }
  const at::Device device = cuda ? at::kCUDA : at::kCPU;
  sfgs::model::Avatar avatar{nullptr};
  std::string description;
  if (!args.run.empty()) {
    avatar = sfgs::train::load_trained_avatar(sfgs::train::RunFolder{args.run}, device).avatar;
    description = "trained avatar of " + args.run;
  } else {
    const std::string bodies = args.shared + "/bodies/";
    const sfgs::model::AvatarBody body =
        args.shared.empty()
            ? sfgs::model::AvatarBody::procedural()
            : sfgs::model::AvatarBody::load(bodies + "anny_smplx_layout.npz", bodies + "anny_mano_left.npz",
                                            bodies + "anny_mano_right.npz", bodies + "MANO_SMPLX_vertex_ids.npz",
                                            bodies + "FLAME_SMPLX_vertex_ids.npy");
    sfgs::model::AvatarConfig config;
    config.subdivision_levels = args.levels;
    avatar = sfgs::model::Avatar(body, at::zeros({10}), config);
    avatar->to(device);
    description = std::string("untrained avatar, ") + (args.shared.empty() ? "procedural" : "Anny") + " body";
  }
  avatar->eval();
  const SmplxPose a = random_pose(11), b = random_pose(12);
  std::printf("sfgs animation benchmark: %s, %ld Gaussians, %s, %d frames per size (median)\n", description.c_str(),
              long(avatar->gaussian_count()), args.device.c_str(), args.frames);
  print_observation_prior(avatar, cuda);
  for (const auto& [width, height] : args.sizes) {
    const sfgs::Camera camera = framing_camera(avatar, a, width, height);
    const at::Tensor white = at::ones({3});
    sfgs::animate::AnimatorOptions eager_options;
    eager_options.use_graph = false;
    sfgs::animate::Animator eager(avatar, camera, white, eager_options);
    time_frames(eager, a, b, 3, cuda);  // warm-up
    if (args.profile) {
      sfgs::animate::Animator graphed(avatar, camera, white);
      time_frames(graphed, a, b, 3, cuda, args.time);  // captures
      sfgs::bench::NvtxStages stages;
      const sfgs::ScopedStageRecorder recording(&stages);
      {
        const sfgs::bench::ProfiledRange range("eager frame");
        eager.render(a, frame_time(args.time, 0));
      }
      {
        const sfgs::bench::ProfiledRange range("graph frame");
        graphed.render(a, frame_time(args.time, 1));
      }
      std::printf("profiled one eager and one graph frame at %ldx%ld\n", long(width), long(height));
      return 0;
    }
    const double eager_ms = median(time_frames(eager, a, b, args.frames, cuda, args.time));
    sfgs::bench::StageClock clock(cuda);
    {
      const sfgs::ScopedStageRecorder recording(&clock);
      for (int k = 0; k < 10; ++k) {
        const sfgs::StageScope frame("frame (eager, synchronised per stage)");
        eager.render(blend(a, b, k / 10.0), frame_time(args.time, k));
      }
    }
    std::printf("%ldx%ld\n", long(width), long(height));
    std::printf("  eager frame: %.3f ms (%.0f frames/s); stages of an eager frame:\n", eager_ms, 1000 / eager_ms);
    clock.print(10, "frame (eager, synchronised per stage)");
    print_tile_runs(avatar, camera, a);
    if (cuda) {
      sfgs::animate::Animator graphed(avatar, camera, white);
      time_frames(graphed, a, b, 3, cuda, args.time);  // captures
      const double graph_ms = median(time_frames(graphed, a, b, args.frames, cuda, args.time));
      const at::Tensor from_graph = graphed.render(a).clone(), from_eager = eager.render(a);
      const double difference = (from_graph - from_eager).abs().max().item<double>();
      const sfgs::animate::AnimatorStats& s = graphed.stats();
      std::printf(
          "  graph frame: %.3f ms (%.0f frames/s); %ld captures, %ld budget overflows, %ld intersections "
          "(budget %ld); largest difference to the eager frame %.2e\n",
          graph_ms, 1000 / graph_ms, long(s.captures), long(s.budget_overflows), long(s.intersections), long(s.budget),
          difference);
      print_batch_table(avatar, camera, white, a, b, args);
      print_culling_table(avatar, camera, white, a, b, args);
      print_blend_segment_table(avatar, camera, white, a, b, args);
    }
  }
  return 0;
}
