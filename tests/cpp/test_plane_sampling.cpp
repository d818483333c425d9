// The fixed-point plane sampling (ops/plane_sampling/plane_sampling.h) against LibTorch's grid_sample (bilinear,
// border, align_corners): the same values, and the planes' gradient of its gather-backward equal to grid_sample's
// scattered one in float64 (points beyond the border, on the far edges, and a thousand on one texel, cut into chunks),
// and to central differences; float32 within rounding; the triplane keeps its reads only while the coordinates are the
// same; mistakes are clear errors.
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "model/planes.h"
#include "ops/plane_sampling/plane_sampling.h"
#include "op_check.h"
#include "test_files.h"

namespace sfgs::testing {
namespace {

using plane_sampling::PlaneReads;

// grid_sample's own values and planes gradient for weights `w` on the output.
std::pair<at::Tensor, at::Tensor> grid_sample_reference(const at::Tensor& planes, const at::Tensor& grid,
                                                        const at::Tensor& w) {
  const at::Tensor p = planes.detach().requires_grad_(true);
  const at::Tensor out =
      at::grid_sampler(p, grid.unsqueeze(1), 0, 1, true).squeeze(2).permute({2, 0, 1}).reshape({grid.size(1), -1});
  const at::Tensor grad = torch::autograd::grad({(out * w).sum()}, {p})[0];
  return {out.detach(), grad};
}

std::pair<at::Tensor, at::Tensor> fixed_sample(const at::Tensor& planes, const at::Tensor& grid, const at::Tensor& w,
                                               const PlaneReads& reads) {
  const at::Tensor p = planes.detach().requires_grad_(true);
  const at::Tensor out = plane_sampling::sample_fixed_planes(p, grid, reads);
  const at::Tensor grad = torch::autograd::grad({(out * w).sum()}, {p})[0];
  return {out.detach(), grad};
}

// Points all over the planes and beyond their border, the four far corners, and `crowd` points on one spot.
at::Tensor test_grid(int64_t planes, int64_t points, int64_t crowd, at::ScalarType dtype) {
  at::Tensor grid = at::rand({planes, points, 2}, at::kDouble) * 2.4 - 1.2;
  const at::Tensor corners =
      at::tensor({-1.0, -1.0, 1.0, -1.0, -1.0, 1.0, 1.0, 1.0}).view({1, 4, 2}).expand({planes, 4, 2});
  const at::Tensor crowded = at::full({planes, crowd, 2}, 0.1234);
  return at::cat({grid, corners, crowded}, 1).to(dtype).contiguous();
}

TEST(PlaneSampling, ValuesAndGradientEqualGridSampleInFloat64) {
  at::manual_seed(1);
  const at::Tensor planes = at::randn({3, 5, 7, 9}, at::kDouble);
  const at::Tensor grid = test_grid(3, 300, 1000, at::kDouble);
  const PlaneReads reads = plane_sampling::plane_reads(grid, 7, 9);
  EXPECT_GT(reads.chunk_rows.size(0), 7 * 9) << "the crowded texel is cut into chunks";
  const at::Tensor w = at::randn({grid.size(1), 15}, at::kDouble);
  const auto [values, gradient] = fixed_sample(planes, grid, w, reads);
  const auto [expected_values, expected_gradient] = grid_sample_reference(planes, grid, w);
  EXPECT_TRUE(values.equal(expected_values));
  EXPECT_LT((gradient - expected_gradient).abs().max().item<double>(), 1e-10);
  EXPECT_GT(expected_gradient.abs().max().item<double>(), 1.0);
}

TEST(PlaneSampling, GradientEqualsCentralDifferences) {
  at::manual_seed(2);
  const at::Tensor planes = at::randn({3, 2, 4, 5}, at::kDouble);
  const at::Tensor grid = test_grid(3, 20, 3, at::kDouble);
  const PlaneReads reads = plane_sampling::plane_reads(grid, 4, 5);
  const at::Tensor w = at::randn({grid.size(1), 6}, at::kDouble);
  const at::Tensor gradient = fixed_sample(planes, grid, w, reads).second;
  const double h = 1e-6;
  for (int64_t k = 0; k < planes.numel(); k += 7) {
    at::Tensor up = planes.clone(), down = planes.clone();
    up.view(-1)[k] += h;
    down.view(-1)[k] -= h;
    const double f_up = (fixed_sample(up, grid, w, reads).first * w).sum().item<double>();
    const double f_down = (fixed_sample(down, grid, w, reads).first * w).sum().item<double>();
    EXPECT_NEAR(gradient.view(-1)[k].item<double>(), (f_up - f_down) / (2 * h), 1e-7) << "entry " << k;
  }
}

TEST(PlaneSampling, Float32MatchesGridSampleWithinRounding) {
  at::manual_seed(3);
  const at::Tensor planes = at::randn({3, 32, 16, 16});
  const at::Tensor grid = test_grid(3, 5000, 200, at::kFloat);
  const PlaneReads reads = plane_sampling::plane_reads(grid, 16, 16);
  const at::Tensor w = at::randn({grid.size(1), 96});
  const at::Tensor gradient = fixed_sample(planes, grid, w, reads).second;
  const at::Tensor expected = grid_sample_reference(planes, grid, w).second;
  EXPECT_LT((gradient - expected).abs().max().item<double>(), 1e-4 * expected.abs().max().item<double>());
}

TEST(PlaneSampling, TriplaneKeepsItsReadsOnlyForTheSameCoordinates) {
  at::manual_seed(4);
  model::Triplane triplane(3, 8);
  at::Tensor coordinates = at::rand({50, 3}) * 2 - 1;
  const auto reference_gradient = [&](const at::Tensor& c) {
    at::Tensor planes;
    for (const auto& p : triplane->named_parameters()) planes = p.value();
    const at::Tensor x = c.select(1, 0), y = c.select(1, 1), z = c.select(1, 2);
    const at::Tensor grid = at::stack({at::stack({x, y}, 1), at::stack({x, z}, 1), at::stack({y, z}, 1)});
    return grid_sample_reference(planes, grid, at::ones({c.size(0), 9})).second;
  };
  const auto gradient = [&](const at::Tensor& c) {
    const at::Tensor out = triplane->sample(c);
    at::Tensor planes;
    for (const auto& p : triplane->named_parameters()) planes = p.value();
    return torch::autograd::grad({out.sum()}, {planes})[0];
  };
  for (int pass = 0; pass < 2; ++pass)  // the second pass reuses the reads
    EXPECT_LT((gradient(coordinates) - reference_gradient(coordinates)).abs().max().item<double>(), 1e-5);
  at::NoGradGuard no_grad;
  coordinates.mul_(0.5);  // the same tensor, other values: new reads
  {
    at::AutoGradMode grad(true);
    EXPECT_LT((gradient(coordinates) - reference_gradient(coordinates)).abs().max().item<double>(), 1e-5);
    const at::Tensor other = at::rand({20, 3}) * 2 - 1;
    EXPECT_LT((gradient(other) - reference_gradient(other)).abs().max().item<double>(), 1e-5);
  }
}

// grid_sample's values and planes gradient of time planes read at positions (P, N) and time t.
std::pair<at::Tensor, at::Tensor> time_reference(const at::Tensor& planes, const at::Tensor& positions, double t,
                                                 const at::Tensor& w) {
  const at::Tensor space = positions.unsqueeze(-1);
  return grid_sample_reference(planes, at::cat({space, at::full_like(space, t)}, -1), w);
}

TEST(PlaneSampling, TimePlanesEqualGridSampleOnBetweenAndBeyondTheRows) {
  at::manual_seed(5);
  const at::Tensor planes = at::randn({3, 5, 6, 9}, at::kDouble);
  const at::Tensor positions = test_grid(3, 200, 500, at::kDouble).select(2, 0).contiguous();
  const at::Tensor line = at::stack({positions, at::full_like(positions, -1)}, -1);
  const PlaneReads reads = plane_sampling::plane_reads(line, 1, 9);
  const at::Tensor w = at::randn({positions.size(1), 15}, at::kDouble);
  for (double t : {-1.0, -0.37, 0.0, 0.6, 1.0, 1.3}) {
    const at::Tensor p = planes.detach().requires_grad_(true);
    const at::Tensor out =
        plane_sampling::sample_fixed_planes_at_time(p, positions, at::scalar_tensor(t, at::kDouble), reads);
    const at::Tensor gradient = torch::autograd::grad({(out * w).sum()}, {p})[0];
    const auto [expected_values, expected_gradient] = time_reference(planes, positions, t, w);
    EXPECT_TRUE(out.detach().equal(expected_values)) << "time " << t;
    EXPECT_LT((gradient - expected_gradient).abs().max().item<double>(), 1e-10) << "time " << t;
  }
}

TEST(PlaneSampling, TimePlanesModuleGradientMatchesGridSampleAtEachTime) {
  at::manual_seed(6);
  model::TimePlanes time_planes(3, 8, 5);
  at::Tensor planes;
  for (const auto& p : time_planes->named_parameters()) planes = p.value();
  const at::Tensor coordinates = at::rand({40, 3}) * 2 - 1;
  const at::Tensor w = at::randn({40, 9});
  for (double t : {0.3, -0.8}) {  // the second time with the reads of the first
    const at::Tensor out = time_planes->sample(coordinates, at::scalar_tensor(t));
    const at::Tensor gradient = torch::autograd::grad({(out * w).sum()}, {planes})[0];
    const at::Tensor expected = time_reference(planes, coordinates.t(), t, w).second;
    EXPECT_LT((gradient - expected).abs().max().item<double>(), 1e-5) << "time " << t;
  }
}

TEST(PlaneSampling, MistakesAreClearErrors) {
  const at::Tensor planes = at::randn({3, 2, 4, 4});
  const at::Tensor grid = at::rand({3, 10, 2}) * 2 - 1;
  const PlaneReads reads = plane_sampling::plane_reads(grid, 4, 4);
  expect_error_mentioning([&] { plane_sampling::plane_reads(grid.select(2, 0), 4, 4); }, "(P, N, 2)");
  expect_error_mentioning([&] { plane_sampling::plane_reads(grid * NAN, 4, 4); }, "finite");
  expect_error_mentioning(
      [&] { plane_sampling::sample_fixed_planes(planes, grid.clone().requires_grad_(true), reads); }, "fixed");
  expect_error_mentioning([&] { plane_sampling::sample_fixed_planes(planes.narrow(2, 0, 3), grid, reads); },
                          "the reads were made for 3 planes of 4 x 4");
  expect_error_mentioning([&] { plane_sampling::sample_fixed_planes(planes.to(at::kDouble), grid, reads); },
                          "grid must be a Double");
  expect_error_mentioning(
      [&] { plane_sampling::sample_fixed_planes_at_time(planes, grid.select(2, 0), at::scalar_tensor(0.0), reads); },
      "one line");
  expect_error_mentioning(
      [&] { plane_sampling::sample_fixed_planes_at_time(planes, grid.select(2, 0), at::zeros({1}), reads); }, "0-dim");
}

TEST(PlaneSampling, AreDispatcherOpsThatRefuseReadsOutsideThePlanes) {
  expect_backend_kernels("sfgs::sample_fixed_planes", true);
  expect_backend_kernels("sfgs::sample_fixed_planes_at_time", true);
  expect_backend_kernels("sfgs::plane_reads_gradient", false);
  at::manual_seed(3);
  const at::Tensor planes = at::randn({3, 2, 4, 5}, at::kDouble), grid = test_grid(3, 20, 5, at::kDouble);
  const PlaneReads reads = plane_sampling::plane_reads(grid, 4, 5);
  const std::vector<c10::IValue> read_arguments = {reads.chunk_rows, reads.chunk_begins, reads.chunk_ends, reads.points,
                                                   reads.weights};
  std::vector<c10::IValue> sample = {planes, grid};
  sample.insert(sample.end(), read_arguments.begin(), read_arguments.end());
  expect_meta_describes_cpu("sfgs::sample_fixed_planes", sample);
  const PlaneReads line = plane_sampling::plane_reads(grid, 1, 5);  // along the width alone: v plays no part
  std::vector<c10::IValue> at_time = {planes,
                                      grid.select(2, 0).contiguous(),
                                      at::scalar_tensor(0.25, at::kDouble),
                                      line.chunk_rows,
                                      line.chunk_begins,
                                      line.chunk_ends,
                                      line.points,
                                      line.weights};
  expect_meta_describes_cpu("sfgs::sample_fixed_planes_at_time", at_time);
  std::vector<c10::IValue> gradient = {at::randn({grid.size(1), 6}, at::kDouble)};
  gradient.insert(gradient.end(), read_arguments.begin(), read_arguments.end());
  for (int64_t size : {3, 2, 4, 5}) gradient.emplace_back(size);
  expect_meta_describes_cpu("sfgs::plane_reads_gradient", gradient);
  // Each of the reads' index tensors with one entry moved beyond what it indexes.
  const c10::OperatorHandle op = registered_op("sfgs::plane_reads_gradient");
  for (size_t k : {1, 2, 3, 4}) {
    std::vector<c10::IValue> bad = gradient;
    at::Tensor t = bad[k].toTensor().clone();
    t[0] = int32_t(k == 1 ? 3 * 4 * 5 : k == 4 ? grid.size(1) : reads.points.size(0) + 1);
    bad[k] = t;
    EXPECT_THROW(call_boxed(op, bad), c10::Error) << "argument " << k;
  }
}

}  // namespace
}  // namespace sfgs::testing
