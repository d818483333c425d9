// The mesh propagation (ops/mesh_propagation/mesh_propagation.h) on the CPU against its definition: rings, smoothing
// passes, trust blend, a part no front reaches, float32 and float64; its plan; and the errors at its boundary.
#include <limits>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "model/constants.h"
#include "ops/mesh_propagation/mesh_propagation.h"
#include "mesh_propagation_cases.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

TEST(MeshPropagation, EqualsItsDefinitionOnABodyWithADetachedPart) {
  const PropagationCase c = body_with_detached_strip();
  const int64_t n = c.trust.size(0);
  const mesh_propagation::Plan plan = mesh_propagation::plan(c.trust, c.neighbours, at::kCPU, at::kDouble);
  EXPECT_GT(plan.ring_count(), 3) << "the front crosses several rings to the back";
  EXPECT_EQ(plan.filled_count() + (c.trust >= 1).sum().item<int64_t>() + 10, n)
      << "every body point is trusted or filled; the strip's 10 are not reached";
  at::Generator g = at::detail::createCPUGenerator(3);
  for (int64_t passes : {int64_t(0), int64_t(1), kObservationSmoothingPasses}) {
    // The plan serves any values (every frame's colours).
    for (int64_t channels : {1, 3, 5}) {
      const at::Tensor values = at::randn({n, channels}, g, at::TensorOptions(at::kDouble));
      const at::Tensor expected = propagation_by_definition(values, c.trust, c.neighbours, passes);
      EXPECT_LT(max_difference(mesh_propagation::propagate(values, plan, passes), expected), 1e-12)
          << passes << " passes, " << channels << " channels";
    }
  }
  const mesh_propagation::Plan single = mesh_propagation::plan(c.trust, c.neighbours, at::kCPU, at::kFloat);
  const at::Tensor values = at::randn({n, 3}, g, at::TensorOptions(at::kDouble));
  const at::Tensor expected = propagation_by_definition(values, c.trust, c.neighbours, kObservationSmoothingPasses);
  EXPECT_LT(
      max_difference(mesh_propagation::propagate(values.to(at::kFloat), single, kObservationSmoothingPasses), expected),
      1e-5);
}

TEST(MeshPropagation, TrustedPointsAndUnreachedPartsKeepTheirValues) {
  const PropagationCase c = body_with_detached_strip();
  const int64_t n = c.trust.size(0);
  const mesh_propagation::Plan plan = mesh_propagation::plan(c.trust, c.neighbours, at::kCPU, at::kDouble);
  const at::Tensor values = at::randn({n, 2}, at::TensorOptions(at::kDouble));
  const at::Tensor out = mesh_propagation::propagate(values, plan, kObservationSmoothingPasses);
  const at::Tensor trusted = (c.trust >= 1).nonzero().squeeze(1);
  EXPECT_TRUE(out.index_select(0, trusted).equal(values.index_select(0, trusted)));
  // The strip: smoothed among its own points only (their values' mean stays within their range).
  const at::Tensor strip = values.narrow(0, n - 10, 10), strip_out = out.narrow(0, n - 10, 10);
  EXPECT_LE(strip_out.max().item<double>(), strip.max().item<double>() + 1e-12);
  EXPECT_GE(strip_out.min().item<double>(), strip.min().item<double>() - 1e-12);
  // Constant values over the body stay constant: every step is a mean.
  const at::Tensor constant = at::full({n, 1}, 0.25, at::kDouble);
  EXPECT_LT(max_difference(mesh_propagation::propagate(constant, plan, 4), constant), 1e-15);
}

TEST(MeshPropagation, NothingTrustedLeavesValuesUnchanged) {
  const PropagationCase c = body_with_detached_strip();
  const mesh_propagation::Plan plan =
      mesh_propagation::plan(at::zeros_like(c.trust), c.neighbours, at::kCPU, at::kFloat);
  EXPECT_FALSE(plan.any_trusted);
  const at::Tensor values = at::randn({c.trust.size(0), 3});
  EXPECT_TRUE(mesh_propagation::propagate(values, plan, kObservationSmoothingPasses).equal(values));
}

// Points without neighbours: no ring reaches them; a smoothing pass gives them the mean of nothing (0), as the
// definition does.
TEST(MeshPropagation, APointCloudWithoutNeighboursIsPlannedToo) {
  body::VertexNeighbours none;
  none.indices = at::zeros({4, 0}, at::kLong);
  none.counts = at::zeros({4}, at::kLong);
  const at::Tensor trust = at::tensor({1.0, 0.0, 0.0, 0.5}, at::kDouble);
  const mesh_propagation::Plan plan = mesh_propagation::plan(trust, none, at::kCPU, at::kDouble);
  EXPECT_EQ(plan.ring_count(), 0);
  const at::Tensor values = at::randn({4, 2}, at::kDouble);
  for (int64_t passes : {0, 2})
    EXPECT_LT(max_difference(mesh_propagation::propagate(values, plan, passes),
                             propagation_by_definition(values, trust, none, passes)),
              1e-15)
        << passes << " passes";
}

TEST(MeshPropagation, RefusesWhatDoesNotFitThePlan) {
  const PropagationCase c = body_with_detached_strip();
  const int64_t n = c.trust.size(0);
  const mesh_propagation::Plan plan = mesh_propagation::plan(c.trust, c.neighbours, at::kCPU, at::kFloat);
  EXPECT_THROW(mesh_propagation::propagate(at::zeros({n - 1, 3}), plan, 1), c10::Error);
  EXPECT_THROW(mesh_propagation::propagate(at::zeros({n, 3}, at::kDouble), plan, 1), c10::Error);
  EXPECT_THROW(mesh_propagation::propagate(at::zeros({n}), plan, 1), c10::Error);
  EXPECT_THROW(mesh_propagation::propagate(at::zeros({n, 3}), plan, -1), c10::Error);
  EXPECT_THROW(mesh_propagation::plan(c.trust.narrow(0, 0, n - 1), c.neighbours, at::kCPU, at::kFloat), c10::Error);
  EXPECT_THROW(mesh_propagation::plan(c.trust, c.neighbours, at::kCPU, at::kHalf), c10::Error);
  at::Tensor not_finite = c.trust.clone();
  not_finite[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(mesh_propagation::plan(not_finite, c.neighbours, at::kCPU, at::kFloat), c10::Error);
  body::VertexNeighbours outside = c.neighbours;
  outside.indices = outside.indices.clone();
  outside.indices[0][0] = n;
  EXPECT_THROW(mesh_propagation::plan(c.trust, outside, at::kCPU, at::kFloat), c10::Error);
}

// The op's arguments from a plan: values, then the plan's tensors and rings in the schema's order.
std::vector<c10::IValue> op_arguments(const at::Tensor& values, const mesh_propagation::Plan& plan, int64_t passes) {
  return {values,
          plan.trust,
          plan.neighbours,
          plan.counts,
          plan.ring_points,
          plan.ring_sources,
          plan.ring_source_counts,
          plan.free_points,
          plan.ring_offsets,
          passes};
}

TEST(MeshPropagation, IsADispatcherOpThatRefusesIndicesOutsideTheMesh) {
  expect_backend_kernels("sfgs::propagate_on_mesh", true);  // its Autograd kernel refuses a gradient
  const PropagationCase c = body_with_detached_strip();
  const int64_t n = c.trust.size(0);
  const mesh_propagation::Plan plan = mesh_propagation::plan(c.trust, c.neighbours, at::kCPU, at::kDouble);
  const at::Tensor values = at::randn({n, 3}, at::kDouble);
  const std::vector<c10::IValue> arguments = op_arguments(values, plan, kObservationSmoothingPasses);
  expect_meta_describes_cpu("sfgs::propagate_on_mesh", arguments);
  const c10::OperatorHandle op = registered_op("sfgs::propagate_on_mesh");
  EXPECT_TRUE(call_boxed(op, arguments)[0].toTensor().equal(
      mesh_propagation::propagate(values, plan, kObservationSmoothingPasses)));
  // Each index tensor with one entry moved outside the mesh, and the rings' bounds beyond the ring points.
  for (size_t k : {2, 3, 4, 5, 6, 7}) {
    std::vector<c10::IValue> bad = arguments;
    at::Tensor t = bad[k].toTensor().clone();
    t.view(-1)[0] = k == 3 || k == 6 ? int32_t(plan.neighbours.size(1) + 1) : int32_t(n);
    bad[k] = t;
    EXPECT_THROW(call_boxed(op, bad), c10::Error) << "argument " << k;
  }
  std::vector<c10::IValue> bad_rings = arguments;
  std::vector<int64_t> offsets = plan.ring_offsets;
  offsets.back() += 1;
  bad_rings[8] = offsets;
  EXPECT_THROW(call_boxed(op, bad_rings), c10::Error);
  const at::Tensor learned = values.clone().requires_grad_(true);
  EXPECT_THROW(call_boxed(op, op_arguments(learned, plan, 1)), c10::Error) << "no gradient";
}

}  // namespace
}  // namespace sfgs::testing
