// The mesh propagation's CUDA kernels (ops/mesh_propagation/mesh_propagation.h) against the CPU backend, in float64 and
// float32, with and without smoothing passes, and recorded in a CUDA graph and replayed on other values. Skips
// without a CUDA device.
#include <ATen/ATen.h>
#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>
#include <gtest/gtest.h>
#include <torch/cuda.h>

#include "model/constants.h"
#include "ops/mesh_propagation/mesh_propagation.h"
#include "mesh_propagation_cases.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

TEST(MeshPropagationCuda, MatchesTheCpuBackend) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const PropagationCase c = body_with_detached_strip();
  const int64_t n = c.trust.size(0);
  at::Generator g = at::detail::createCPUGenerator(9);
  for (at::ScalarType dtype : {at::kDouble, at::kFloat}) {
    const mesh_propagation::Plan cpu = mesh_propagation::plan(c.trust, c.neighbours, at::kCPU, dtype);
    const mesh_propagation::Plan gpu = mesh_propagation::plan(c.trust.cuda(), c.neighbours, at::kCUDA, dtype);
    EXPECT_EQ(gpu.ring_offsets, cpu.ring_offsets);
    for (int64_t passes : {int64_t(0), kObservationSmoothingPasses}) {
      const at::Tensor values = at::randn({n, 3}, g, at::TensorOptions(at::kDouble)).to(dtype);
      const double tolerance = dtype == at::kDouble ? 1e-13 : 1e-5;
      EXPECT_LT(max_difference(mesh_propagation::propagate(values.cuda(), gpu, passes),
                               mesh_propagation::propagate(values, cpu, passes)),
                tolerance)
          << dtype << ", " << passes << " passes";
    }
  }
}

TEST(MeshPropagationCuda, ReplaysInACudaGraph) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const PropagationCase c = body_with_detached_strip();
  const int64_t n = c.trust.size(0);
  const mesh_propagation::Plan plan = mesh_propagation::plan(c.trust.cuda(), c.neighbours, at::kCUDA, at::kFloat);
  const at::Tensor input = at::randn({n, 3}, at::kCUDA);
  at::Tensor output;
  const c10::cuda::CUDAStream stream = c10::cuda::getStreamFromPool();
  at::cuda::CUDAGraph graph;
  {
    const c10::cuda::CUDAStreamGuard guard(stream);
    mesh_propagation::propagate(input, plan, kObservationSmoothingPasses);  // warm-up on the capture stream
    graph.capture_begin();
    output = mesh_propagation::propagate(input, plan, kObservationSmoothingPasses);
    graph.capture_end();
  }
  for (int k = 0; k < 2; ++k) {
    input.copy_(at::randn({n, 3}, at::kCUDA));
    graph.replay();
    torch::cuda::synchronize();
    EXPECT_LT(max_difference(output, mesh_propagation::propagate(input, plan, kObservationSmoothingPasses)), 1e-6);
  }
}

// An index outside the mesh, which the CUDA op cannot check without reading the device: a source outside gives its
// point NaN, a target outside is skipped, and nothing outside the arrays is touched (memcheck in device_check.sh).
TEST(MeshPropagationCudaSanitizer, IndicesOutsideTheMeshGiveNanNotAStrayAccess) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  const PropagationCase c = body_with_detached_strip();
  const int64_t n = c.trust.size(0);
  mesh_propagation::Plan plan = mesh_propagation::plan(c.trust.cuda(), c.neighbours, at::kCUDA, at::kFloat);
  ASSERT_GT(plan.filled_count(), 1);
  const at::Tensor values = at::randn({n, 3}).cuda();
  const int32_t first = plan.ring_points[0].item<int32_t>(), second = plan.ring_points[1].item<int32_t>();
  plan.ring_sources = plan.ring_sources.clone();
  plan.ring_sources[0][0] = int32_t(n + 5);
  plan.ring_points = plan.ring_points.clone();
  plan.ring_points[1] = int32_t(-3);
  const at::Tensor after = mesh_propagation::propagate(values, plan, 0).cpu();
  EXPECT_TRUE(after[first].isnan().any().item<bool>()) << "its source lies outside the mesh";
  EXPECT_TRUE(at::allclose(after[second], values[second].cpu(), 1e-6, 1e-6))
      << "a target outside the mesh is skipped: point " << second << " keeps its own value";
}

}  // namespace
}  // namespace sfgs::testing
