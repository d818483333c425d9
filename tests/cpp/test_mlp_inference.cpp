// The MLP inference op (ops/mlp_inference/mlp_inference.h) on the CPU: its reference is the avatar's GroupNorm MLP
// (model/mlp.h), whole and with a group given as column blocks over a base; run() falls back to it; bad shapes,
// dtypes and gradients are refused by name. The fused kernel is tested on the device (tests/cuda).
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "mlp_inference_cases.h"
#include "model/mlp.h"
#include "op_check.h"
#include "tensor_compare.h"

namespace sfgs::testing {
namespace {

// A GroupNorm network of the avatar's kind, in float64, with a non-zero output layer.
model::Mlp random_mlp(const std::vector<int64_t>& input_widths) {
  model::Mlp mlp(model::MlpShape{input_widths, {8, 8, 8}, 3, /*group_norm=*/true, /*zero_output=*/false});
  mlp->to(at::kDouble);
  at::Generator g = at::detail::createCPUGenerator(3);
  at::NoGradGuard no_grad;
  for (at::Tensor& p : mlp->parameters()) p.copy_(at::randn(p.sizes(), g, at::TensorOptions(at::kDouble)) * 0.5);
  return mlp;
}

TEST(MlpInference, ReferenceIsTheAvatarsNetwork) {
  const model::Mlp mlp = random_mlp({5, 7});
  at::Generator g = at::detail::createCPUGenerator(4);
  const at::Tensor a = at::randn({37, 5}, g, at::TensorOptions(at::kDouble));
  const at::Tensor b = at::randn({37, 7}, g, at::TensorOptions(at::kDouble));
  // In grad mode the network takes its layers one by one (the fused GroupNorm ops): an independent path.
  const at::Tensor expected = mlp->forward({a, b});
  EXPECT_LT(max_difference(mlp_inference::reference({a, b}, at::Tensor(), mlp->inference_network(0, {})), expected),
            1e-12);

  // Group 1 given as two column blocks over a base (the colour offset's call).
  const at::Tensor base = mlp->project(0, a);
  const at::Tensor first = b.narrow(1, 0, 4), second = b.narrow(1, 4, 3);
  const at::Tensor blocks = mlp_inference::reference({first, second}, base, mlp->inference_network(1, {4, 3}));
  EXPECT_LT(max_difference(blocks, expected), 1e-12);
  at::NoGradGuard no_grad;
  EXPECT_LT(max_difference(mlp->finish_from(base, 1, {first, second}), expected), 1e-12);
}

TEST(MlpInference, RunFallsBackToTheReferenceOffCuda) {
  at::Generator g = at::detail::createCPUGenerator(5);
  const mlp_inference::Network n = random_network(16, {6, 3}, 2, 4, g);
  const std::vector<at::Tensor> inputs = random_inputs(21, n, g);
  EXPECT_FALSE(mlp_inference::fuses(inputs, n));
  EXPECT_FALSE(mlp_inference::fuses(inputs, mlp_inference::Network{})) << "a bad network is a no, not a crash";
  at::NoGradGuard no_grad;
  EXPECT_TRUE(mlp_inference::run(inputs, at::Tensor(), n).equal(mlp_inference::reference(inputs, at::Tensor(), n)));
}

TEST(MlpInference, IsADispatcherOpWhoseMetaKernelDescribesItsOutput) {
  expect_backend_kernels("sfgs::mlp_inference", true);  // its Autograd kernel refuses a gradient
  at::Generator g = at::detail::createCPUGenerator(7);
  const mlp_inference::Network n = random_network(16, {6, 3}, 3, 4, g);
  const std::vector<at::Tensor> inputs = random_inputs(21, n, g);
  const at::Tensor base = at::randn({21, 16}, g, at::TensorOptions(at::kDouble));
  const std::vector<c10::IValue> arguments = {
      inputs,         base,          n.input_weights, n.first_bias,  n.hidden_weights, n.hidden_biases,
      n.norm_weights, n.norm_biases, n.output_weight, n.output_bias, n.groups,         n.epsilon};
  at::NoGradGuard no_grad;
  expect_meta_describes_cpu("sfgs::mlp_inference", arguments);
  const at::Tensor out = call_boxed(registered_op("sfgs::mlp_inference"), arguments)[0].toTensor();
  EXPECT_TRUE(out.equal(mlp_inference::reference(inputs, base, n)));
}

TEST(MlpInference, RefusesBadNetworksAndInputsByName) {
  at::Generator g = at::detail::createCPUGenerator(6);
  const mlp_inference::Network n = random_network(16, {6}, 2, 4, g);
  const std::vector<at::Tensor> inputs = random_inputs(10, n, g);
  const auto refuses = [&](const std::vector<at::Tensor>& in, const at::Tensor& base, const mlp_inference::Network& net,
                           const std::string& expected) {
    try {
      at::NoGradGuard no_grad;
      mlp_inference::run(in, base, net);
      ADD_FAILURE() << "accepted; expected an error naming " << expected;
    } catch (const c10::Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  };
  refuses({inputs[0].narrow(1, 0, 5)}, at::Tensor(), n, "input 0");
  refuses({inputs[0].to(at::kFloat)}, at::Tensor(), n, "input 0");
  refuses({inputs[0], inputs[0]}, at::Tensor(), n, "input weight blocks");
  refuses(inputs, at::zeros({9, 16}, at::kDouble), n, "base");
  mlp_inference::Network missing = n;
  missing.hidden_weights.clear();
  refuses(inputs, at::Tensor(), missing, "hidden layers");
  mlp_inference::Network wide = n;
  wide.output_bias = at::zeros({5}, at::kDouble);
  refuses(inputs, at::Tensor(), wide, "output_bias");
  mlp_inference::Network groups = n;
  groups.groups = 3;
  refuses(inputs, at::Tensor(), groups, "groups");

  // Inference only: a weight that requires a gradient in grad mode is refused.
  mlp_inference::Network learning = n;
  learning.output_weight = learning.output_weight.clone().requires_grad_();
  EXPECT_THROW(mlp_inference::run(inputs, at::Tensor(), learning), c10::Error);
}

}  // namespace
}  // namespace sfgs::testing
