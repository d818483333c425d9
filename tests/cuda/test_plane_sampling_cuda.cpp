// The planes' backward on the GPU (ops/plane_sampling/plane_sampling.h): the CUDA kernel against the CPU backend in
// float64 (the reads made on each device; the triplanes and the time planes), and against grid_sample's own CUDA
// backward in float32, at the avatar's scale (215k points clustered like a body, a crowded texel); a small case for
// compute-sanitizer (PlaneSamplingCudaSanitizer.*). Skips without a CUDA device.
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <ATen/core/dispatch/Dispatcher.h>
#include <torch/cuda.h>

#include "ops/plane_sampling/plane_sampling.h"

namespace sfgs::testing {
namespace {

#define SKIP_WITHOUT_CUDA() \
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device"

// Points clustered around the middle (most texels read by few points, some by hundreds) and a crowd on one spot.
at::Tensor clustered_grid(int64_t points, int64_t crowd) {
  const at::Tensor spread = (at::randn({3, points, 2}, at::kDouble) * 0.35).clamp(-1.1, 1.1);
  return at::cat({spread, at::full({3, crowd, 2}, -0.25, at::kDouble)}, 1).contiguous();
}

at::Tensor planes_gradient(const at::Tensor& planes, const at::Tensor& grid, const at::Tensor& w, bool fixed) {
  const at::Tensor p = planes.detach().requires_grad_(true);
  at::Tensor out;
  if (fixed) {
    const plane_sampling::PlaneReads reads = plane_sampling::plane_reads(grid, planes.size(2), planes.size(3));
    out = plane_sampling::sample_fixed_planes(p, grid, reads);
  } else {
    out = at::grid_sampler(p, grid.unsqueeze(1), 0, 1, true).squeeze(2).permute({2, 0, 1}).reshape({grid.size(1), -1});
  }
  return torch::autograd::grad({(out * w).sum()}, {p})[0];
}

// Time planes (3, C, 32, side) at a time between two rows: the CUDA backward against the CPU one in float64.
void expect_time_planes_cuda_equals_cpu(int64_t channels, int64_t side, int64_t points) {
  at::manual_seed(8);
  const at::Tensor planes = at::randn({3, channels, 32, side}, at::kDouble);
  const at::Tensor positions = clustered_grid(points, points / 10).select(2, 0).contiguous();
  const at::Tensor w = at::randn({positions.size(1), 3 * channels}, at::kDouble);
  const auto gradient = [&](const at::Device device) {
    const at::Tensor p = planes.to(device).requires_grad_(true), x = positions.to(device);
    const at::Tensor line = at::stack({x, at::full_like(x, -1)}, -1);
    const plane_sampling::PlaneReads reads = plane_sampling::plane_reads(line, 1, side);
    const at::Tensor out =
        plane_sampling::sample_fixed_planes_at_time(p, x, at::scalar_tensor(0.37, p.options()), reads);
    return torch::autograd::grad({(out * w.to(device)).sum()}, {p})[0].cpu();
  };
  const at::Tensor cpu = gradient(at::kCPU), gpu = gradient(at::kCUDA);
  EXPECT_LT((gpu - cpu).abs().max().item<double>(), 1e-10 * (1 + cpu.abs().max().item<double>()));
}

void expect_cuda_equals_cpu(int64_t channels, int64_t side, int64_t points, int64_t crowd) {
  at::manual_seed(5);
  const at::Tensor planes = at::randn({3, channels, side, side}, at::kDouble);
  const at::Tensor grid = clustered_grid(points, crowd);
  const at::Tensor w = at::randn({grid.size(1), 3 * channels}, at::kDouble);
  const at::Tensor cpu = planes_gradient(planes, grid, w, true);
  const at::Tensor gpu = planes_gradient(planes.cuda(), grid.cuda(), w.cuda(), true).cpu();
  EXPECT_LT((gpu - cpu).abs().max().item<double>(), 1e-10 * (1 + cpu.abs().max().item<double>()));
}

TEST(PlaneSamplingCuda, GradientEqualsTheCpuBackendAndGridSample) {
  SKIP_WITHOUT_CUDA();
  expect_cuda_equals_cpu(32, 128, 215000, 3000);
  expect_time_planes_cuda_equals_cpu(32, 128, 215000);
  // float32 at the same scale against grid_sample's CUDA backward (atomic adds in another order).
  at::manual_seed(6);
  const at::Tensor planes = at::randn({3, 32, 128, 128}, at::kCUDA);
  const at::Tensor grid = clustered_grid(215000, 3000).to(at::kCUDA, at::kFloat);
  const at::Tensor w = at::randn({grid.size(1), 96}, at::kCUDA);
  const at::Tensor fixed = planes_gradient(planes, grid, w, true);
  const at::Tensor reference = planes_gradient(planes, grid, w, false);
  EXPECT_LT((fixed - reference).abs().max().item<double>(), 1e-4 * reference.abs().max().item<double>());
}

TEST(PlaneSamplingCudaSanitizer, SmallPlanesInBothDtypes) {
  SKIP_WITHOUT_CUDA();
  expect_cuda_equals_cpu(5, 8, 300, 100);
  expect_cuda_equals_cpu(40, 6, 50, 70);  // more channels than a warp has lanes
  expect_time_planes_cuda_equals_cpu(5, 8, 300);
  at::manual_seed(7);
  const at::Tensor planes = at::randn({3, 4, 8, 8}, at::kCUDA);
  const at::Tensor grid = clustered_grid(200, 50).to(at::kCUDA, at::kFloat);
  const at::Tensor w = at::randn({grid.size(1), 12}, at::kCUDA);
  EXPECT_LT(
      (planes_gradient(planes, grid, w, true) - planes_gradient(planes, grid, w, false)).abs().max().item<double>(),
      1e-4);
}

// Reads the CUDA op cannot check without reading the device: a chunk with a point beyond the gradient's rows gives
// its texel NaN, a chunk whose texel lies beyond the planes is skipped; nothing outside the arrays is read or written
// (memcheck in device_check.sh).
TEST(PlaneSamplingCudaSanitizer, ReadsOutsideTheArraysGiveNanNotAStrayAccess) {
  SKIP_WITHOUT_CUDA();
  at::manual_seed(9);
  const at::Tensor grid = clustered_grid(40, 10).to(at::kCUDA, at::kFloat);
  const plane_sampling::PlaneReads reads = plane_sampling::plane_reads(grid, 4, 4);
  const at::Tensor grad = at::randn({grid.size(1), 3 * 2}, at::kCUDA);
  const auto op = c10::Dispatcher::singleton().findSchemaOrThrow("sfgs::plane_reads_gradient", "");
  const auto gradient_of = [&](const at::Tensor& chunk_rows, const at::Tensor& points) {
    std::vector<c10::IValue> stack = {grad,          chunk_rows, reads.chunk_begins, reads.chunk_ends, points,
                                      reads.weights, int64_t(3), int64_t(2),         int64_t(4),       int64_t(4)};
    op.callBoxed(&stack);
    return stack[0].toTensor().cpu();
  };
  const at::Tensor clean = gradient_of(reads.chunk_rows, reads.points);
  ASSERT_TRUE(clean.isfinite().all().item<bool>());
  at::Tensor points = reads.points.clone();
  points[reads.chunk_begins[0].item<int32_t>()] = int32_t(grid.size(1) + 3);
  const int32_t texel = reads.chunk_rows[0].item<int32_t>();
  const at::Tensor bad_point = gradient_of(reads.chunk_rows, points);
  EXPECT_TRUE(bad_point.view({3, 2, 16}).select(0, texel / 16).select(1, texel % 16).isnan().all().item<bool>());
  at::Tensor chunk_rows = reads.chunk_rows.clone();
  chunk_rows[0] = int32_t(3 * 16 + 5);
  const at::Tensor bad_texel = gradient_of(chunk_rows, reads.points);
  EXPECT_TRUE(bad_texel.isfinite().all().item<bool>()) << "the chunk beyond the planes is skipped";
  torch::cuda::synchronize();
}

}  // namespace
}  // namespace sfgs::testing
