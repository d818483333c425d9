// The gathered MLP (csrc/gathered_mlp/gathered_mlp.h) on the CPU, where it is its LibTorch reference: the same
// function as the structure offset's network on the concatenated inputs, the structure offset's inference path equal
// to its training path, and clear errors at its boundary. The fused CUDA kernel is compared with this reference in
// tests/cuda/test_animate_cuda.cpp.
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>

#include <string>

#include "gathered_mlp/gathered_mlp.h"
#include "model/mlp.h"
#include "model/structure_offset.h"
#include "test_files.h"

namespace sfgs::testing {
namespace {

// Every parameter of `module` replaced by N(0, std^2) noise (the output layers start at zero).
void randomise(torch::nn::Module& module, double std, uint64_t seed) {
  at::NoGradGuard no_grad;
  at::Generator generator = at::detail::createCPUGenerator(seed);
  for (auto& p : module.parameters()) p.copy_(at::normal(0, std, p.sizes(), generator));
}

TEST(GatheredMlp, IsTheNetworkOnTheConcatenatedInputs) {
  const int64_t n = 37, h = 16, rows_width = 5, groups_width = 3, groups = 4;
  model::Mlp mlp(model::MlpShape{{rows_width, groups_width}, {h, h}, 4, false, true});
  randomise(*mlp, 0.5, 3);
  const at::Tensor row_features = at::randn({n, rows_width}), group_features = at::randn({groups, groups_width});
  const at::Tensor ids = at::randint(groups, {n}, at::kLong);
  at::NoGradGuard no_grad;
  const at::Tensor gathered = gathered_mlp::gathered_mlp(mlp->project(0, row_features), mlp->project(1, group_features),
                                                         ids.to(at::kInt), mlp->gathered_weights());
  const at::Tensor whole = mlp->forward({row_features, group_features.index_select(0, ids)});
  EXPECT_TRUE(at::allclose(gathered, whole, 1e-5, 1e-6)) << (gathered - whole).abs().max();
  EXPECT_GT(whole.abs().max().item<double>(), 0.1) << "the network is not the constant zero";
}

TEST(GatheredMlp, StructureOffsetInferenceEqualsItsTrainingPath) {
  const int64_t joints = 55, n = 300, width = 12, hidden = 16;
  const at::Tensor canonical_joints = at::randn({joints, 3}), dominant = at::randint(joints, {n}, at::kLong);
  model::StructureOffset offset(width, hidden, 4, canonical_joints, dominant);
  randomise(*offset, 0.3, 5);
  const at::Tensor projection = offset->project_features(at::randn({n, width})), rotations = at::randn({joints, 6});
  at::NoGradGuard no_grad;
  const model::StructureOffsetOutput training = offset->forward(projection, rotations);
  const model::StructureOffsetOutput inference = offset->forward_inference(projection, rotations);
  EXPECT_TRUE(at::allclose(training.mean_offset, inference.mean_offset, 1e-5, 1e-6));
  EXPECT_TRUE(at::allclose(training.log_scale_offset, inference.log_scale_offset, 1e-5, 1e-6));
}

TEST(GatheredMlp, RefusesBadInputsByName) {
  const int64_t n = 8, h = 4, groups = 3;
  gathered_mlp::GatheredMlpWeights w{at::randn({h, h}), at::randn({h}), at::randn({2, h}), at::randn({2})};
  const at::Tensor rows = at::randn({n, h}), group_rows = at::randn({groups, h});
  const at::Tensor ids = at::randint(groups, {n}, at::kInt);
  at::NoGradGuard no_grad;
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows.narrow(1, 0, 3), group_rows, ids, w); },
                          "hidden_weight must be a floating (3, 3) tensor");
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids.narrow(0, 0, 5), w); },
                          "groups must be an int32 or int64 (8) tensor");
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids.to(at::kFloat), w); },
                          "groups must be an int32 or int64");
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids + groups, w); },
                          "groups must lie in [0, 3)");
  gathered_mlp::GatheredMlpWeights doubles = w;
  doubles.output_bias = w.output_bias.to(at::kDouble);
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(rows, group_rows, ids, doubles); },
                          "output_bias must be a Float tensor of shape [2]");
  at::GradMode::set_enabled(true);
  const at::Tensor learned = rows.clone().requires_grad_(true);
  expect_error_mentioning([&] { gathered_mlp::gathered_mlp(learned, group_rows, ids, w); }, "inference only");
  at::GradMode::set_enabled(false);
  EXPECT_FALSE(gathered_mlp::fuses(rows, w)) << "CPU tensors take the reference";
}

}  // namespace
}  // namespace sfgs::testing
