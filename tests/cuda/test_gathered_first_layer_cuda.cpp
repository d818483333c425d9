// The gathered first layer's CUDA kernels (ops/gathered_mlp/gathered_mlp.h: gathered_first_layer) against the CPU
// backend: float64 parity of the value and both gradients at the training size (215,782 rows of 128 in 55 groups, every
// group used) and odd shapes, group tables that opt in to more shared memory or exceed it, float32 through the float4
// and the scalar forward against float64, rows of an out-of-range group (NaN, no gradient, the other rows and the
// groups' gradient unchanged), and small cases for compute-sanitizer. Skips without a CUDA device.
#include <algorithm>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/cuda.h>

#include "ops/gathered_mlp/gathered_mlp.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

const auto kLongs = at::TensorOptions().dtype(at::kLong);
constexpr double kSingleTolerance = 1e-5;  // float32 against float64, relative to the largest value

double largest(const at::Tensor& t) { return t.numel() == 0 ? 0.0 : t.abs().max().item<double>(); }

struct Inputs {
  at::Tensor rows, group_rows, groups, weights;  // float64 and int64 on the CPU; weights: the output's in the loss
};

// n rows of width h in g groups; the first rows take groups 0, 1, ... so that every group has rows when n >= g.
Inputs random_inputs(int64_t n, int64_t h, int64_t g, uint64_t seed) {
  at::Generator generator = at::detail::createCPUGenerator(seed);
  const at::Tensor groups = at::randint(g, {n}, generator, kLongs);
  const int64_t listed = std::min(n, g);
  groups.narrow(0, 0, listed).copy_(at::arange(listed, kLongs));
  return {at::randn({n, h}, generator, kF64), at::randn({g, h}, generator, kF64), groups,
          at::randn({n, h}, generator, kF64)};
}

struct Result {
  at::Tensor out, grad_rows, grad_groups;  // float64 on the CPU
};

// The op on `device` in `dtype` with the gradients of sum(out * weights). `offset` > 0 starts row_inputs that many
// values into a larger array, so that the forward cannot take float4 loads.
Result run_on(const Inputs& in, at::Device device, at::ScalarType dtype, int64_t offset = 0) {
  const at::Tensor flat = at::zeros({in.rows.numel() + offset}, at::TensorOptions().dtype(dtype).device(device));
  flat.narrow(0, offset, in.rows.numel()).copy_(in.rows.flatten());
  const at::Tensor rows = flat.narrow(0, offset, in.rows.numel()).view(in.rows.sizes()).requires_grad_(true);
  const at::Tensor group_rows = in.group_rows.to(device, dtype).requires_grad_(true);
  const at::Tensor out = gathered_mlp::gathered_first_layer(rows, group_rows, in.groups.to(device));
  const auto grads = torch::autograd::grad({(out * in.weights.to(device, dtype)).sum()}, {rows, group_rows});
  return {out.detach().to(at::kCPU, at::kDouble), grads[0].to(at::kCPU, at::kDouble),
          grads[1].to(at::kCPU, at::kDouble)};
}

// The rows' outputs and gradients equal, the groups' gradient (sums in another order) within `tolerance` of the
// largest; float32 results within kSingleTolerance of the largest of each.
void expect_close(const Result& got, const Result& expected, bool single, const std::string& what) {
  const double rows_tolerance = single ? kSingleTolerance : 0.0;
  const double groups_tolerance = single ? kSingleTolerance : 1e-12;
  EXPECT_LE(max_difference(got.out, expected.out), rows_tolerance * largest(expected.out)) << what << ": out";
  EXPECT_LE(max_difference(got.grad_rows, expected.grad_rows), rows_tolerance * largest(expected.grad_rows))
      << what << ": row gradient";
  EXPECT_LE(max_difference(got.grad_groups, expected.grad_groups),
            groups_tolerance * std::max(1.0, largest(expected.grad_groups)))
      << what << ": group gradient";
}

void expect_parity(int64_t n, int64_t h, int64_t g) {
  const Inputs in = random_inputs(n, h, g, 5);
  const Result cpu = run_on(in, at::kCPU, at::kDouble);
  const std::string what = std::to_string(n) + " x " + std::to_string(h) + " in " + std::to_string(g);
  expect_close(run_on(in, at::kCUDA, at::kDouble), cpu, false, what + " (float64)");
  for (int64_t offset : {0, 1})  // the float4 forward where the width allows, then the scalar one
    expect_close(run_on(in, at::kCUDA, at::kFloat, offset), cpu, true,
                 what + " (float32, offset " + std::to_string(offset) + ")");
  EXPECT_GT(largest(cpu.grad_groups), 0.0) << what;
}

// Rows whose group is outside [0, g) (past the end, negative, far past) get NaN and no gradient; the other rows and
// the groups' gradient are those of the same inputs without them.
void expect_invalid_groups_ignored(int64_t n, int64_t h, int64_t g) {
  const Inputs in = random_inputs(n, h, g, 9);
  const std::vector<int64_t> bad_rows = {1, n / 2, n - 1};
  const std::vector<int64_t> bad_groups = {g, -1, 1000000};
  Inputs bad = in;
  bad.groups = in.groups.clone();
  at::Tensor good = at::ones({n}, at::kBool);
  for (size_t k = 0; k < bad_rows.size(); ++k) {
    bad.groups[bad_rows[k]] = bad_groups[k];
    good[bad_rows[k]] = false;
  }
  const at::Tensor good_rows = at::nonzero(good).flatten(), bad_index = at::tensor(bad_rows, kLongs);
  const Inputs kept{in.rows.index_select(0, good_rows), in.group_rows, in.groups.index_select(0, good_rows),
                    in.weights.index_select(0, good_rows)};
  const Result expected = run_on(kept, at::kCPU, at::kDouble);
  for (at::ScalarType dtype : {at::kDouble, at::kFloat}) {
    const std::string what = std::to_string(n) + " x " + std::to_string(h) + " in " + std::to_string(g) + " " +
                             std::string(c10::toString(dtype));
    const Result got = run_on(bad, at::kCUDA, dtype);
    EXPECT_TRUE(at::isnan(got.out.index_select(0, bad_index)).all().item<bool>()) << what;
    EXPECT_EQ(largest(got.grad_rows.index_select(0, bad_index)), 0.0) << what;
    const Result got_good{got.out.index_select(0, good_rows), got.grad_rows.index_select(0, good_rows),
                          got.grad_groups};
    expect_close(got_good, expected, dtype == at::kFloat, what);
  }
}

TEST(GatheredFirstLayerCuda, MatchesTheCpuBackend) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_parity(215782, 128, 55);  // the default avatar's points, hidden width and joints
  expect_parity(1001, 7, 3);       // a width of no multiple of four: the scalar forward
  expect_parity(33, 1, 1);
}

// Group tables past 48 KiB: 200 KiB of float opts in to more shared memory (where the device allows it), 400 KiB of
// double is past every device's and goes to the global table.
TEST(GatheredFirstLayerCuda, TablesBeyondTheDefaultSharedMemory) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_parity(20000, 128, 400);
}

TEST(GatheredFirstLayerCuda, RowsOfAnInvalidGroupAreNanAndPassNothingOn) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_invalid_groups_ignored(215782, 128, 55);
  expect_invalid_groups_ignored(1001, 7, 3);
}

TEST(GatheredFirstLayerCudaSanitizer, SmallCases) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  expect_parity(5, 8, 2);
  expect_parity(3, 3, 3);
  expect_parity(40, 16, 300);   // more groups than rows
  expect_parity(20, 128, 240);  // 240 KiB of double: the global table
  expect_invalid_groups_ignored(12, 8, 3);
  expect_invalid_groups_ignored(9, 5, 2);
}

}  // namespace
}  // namespace sfgs::testing
