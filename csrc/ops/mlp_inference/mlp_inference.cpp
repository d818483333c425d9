// The MLP inference op: validation at the boundary, the LibTorch reference, the fused kernel where it applies, and its
// dispatcher registration (ops/registration.h).
#include "ops/mlp_inference/mlp_inference.h"

#include <cstdint>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/group_norm/group_norm.h"
#include "ops/mlp_inference/backend.h"
#include "ops/registration.h"

namespace sfgs::mlp_inference {
namespace {

// Checks every shape, dtype and device; returns the hidden width H.
int64_t check_network(const std::vector<at::Tensor>& inputs, const at::Tensor& base, const Network& n) {
  TORCH_CHECK(!n.input_weights.empty() && inputs.size() == n.input_weights.size(),
              "mlp_inference: ", n.input_weights.size(),
              " input weight blocks need as many input blocks (at least one), got ", inputs.size());
  TORCH_CHECK(n.input_weights[0].defined() && n.input_weights[0].dim() == 2 &&
                  at::isFloatingType(n.input_weights[0].scalar_type()),
              "mlp_inference: input weight 0 must be a floating (H, I) tensor, got ", describe(n.input_weights[0]));
  const int64_t h = n.input_weights[0].size(0);
  const at::ScalarType dtype = n.input_weights[0].scalar_type();
  const at::Device device = n.input_weights[0].device();
  const auto check = [&](const at::Tensor& t, const std::string& name, at::IntArrayRef shape) {
    check_tensor(t, "mlp_inference: " + name, shape, dtype, device);
  };
  TORCH_CHECK(inputs[0].defined() && inputs[0].dim() == 2, "mlp_inference: input 0 must be an (N, I) tensor, got ",
              describe(inputs[0]));
  const int64_t rows = inputs[0].size(0);
  for (size_t b = 0; b < inputs.size(); ++b) {
    const std::string block = std::to_string(b);
    TORCH_CHECK(n.input_weights[b].defined() && n.input_weights[b].dim() == 2, "mlp_inference: input weight ", block,
                " must be an (H, I) tensor, got ", describe(n.input_weights[b]));
    check(n.input_weights[b], "input weight " + block, {h, n.input_weights[b].size(1)});
    check(inputs[b], "input " + block, {rows, n.input_weights[b].size(1)});
  }
  if (base.defined()) check(base, "base", {rows, h});
  check(n.first_bias, "first_bias", {h});
  const size_t layers = n.norm_weights.size();
  TORCH_CHECK(layers >= 1 && n.norm_biases.size() == layers && n.hidden_weights.size() == layers - 1 &&
                  n.hidden_biases.size() == layers - 1,
              "mlp_inference: a network of L >= 1 hidden layers has L GroupNorm weights and biases and L - 1 hidden "
              "weights and biases, got ",
              n.norm_weights.size(), ", ", n.norm_biases.size(), ", ", n.hidden_weights.size(), " and ",
              n.hidden_biases.size());
  for (size_t k = 0; k < layers; ++k) {
    check(n.norm_weights[k], "norm weight " + std::to_string(k), {h});
    check(n.norm_biases[k], "norm bias " + std::to_string(k), {h});
    if (k == 0) continue;
    check(n.hidden_weights[k - 1], "hidden weight " + std::to_string(k), {h, h});
    check(n.hidden_biases[k - 1], "hidden bias " + std::to_string(k), {h});
  }
  TORCH_CHECK(n.output_weight.defined() && n.output_weight.dim() == 2 && n.output_weight.size(0) >= 1,
              "mlp_inference: output_weight must be an (O, ", h, ") tensor with O >= 1, got ",
              describe(n.output_weight));
  check(n.output_weight, "output_weight", {n.output_weight.size(0), h});
  check(n.output_bias, "output_bias", {n.output_weight.size(0)});
  TORCH_CHECK(n.groups >= 1 && h % n.groups == 0, "mlp_inference: ", n.groups, " GroupNorm groups do not divide ", h,
              " hidden units");
  TORCH_CHECK(n.epsilon > 0, "mlp_inference: GroupNorm's epsilon must be positive, got ", n.epsilon);
  return h;
}

// The kernel reads biases, GroupNorm's parameters, hidden and output weights and the base two floats at a time.
constexpr uintptr_t kPairAlignment = 2 * sizeof(float);

// The tensor as the kernel reads it: rows of unit column stride (a column slice keeps its row stride).
at::Tensor rows_of_unit_stride(const at::Tensor& t) { return t.stride(1) == 1 ? t : t.contiguous(); }

// The fused kernel (fuses() holds).
at::Tensor fused_network(const std::vector<at::Tensor>& inputs, const at::Tensor& base, const Network& n) {
#if defined(SFGS_WITH_CUDA)
  std::vector<at::Tensor> kept;  // what the arrays point into, alive until the kernel is queued
  const auto keep = [&kept](const at::Tensor& t) -> const float* {
    kept.push_back(rows_of_unit_stride(t));
    return kept.back().data_ptr<float>();
  };
  // Read in pairs: contiguous and aligned (a slice at an odd offset is copied).
  const auto keep_contiguous = [&kept](const at::Tensor& t) -> const float* {
    at::Tensor c = t.contiguous();
    if (reinterpret_cast<uintptr_t>(c.data_ptr()) % kPairAlignment != 0) c = c.clone();
    kept.push_back(c);
    return kept.back().data_ptr<float>();
  };
  MlpInferenceArrays a;
  a.input_count = int(inputs.size());
  a.paired_inputs = true;
  for (size_t b = 0; b < inputs.size(); ++b) {
    InputBlock& block = a.inputs[b];
    block.values = keep(inputs[b]);
    block.values_stride = kept.back().stride(0);
    block.weight = keep(n.input_weights[b]);
    block.weight_stride = kept.back().stride(0);
    block.width = int(inputs[b].size(1));
    a.paired_inputs = a.paired_inputs && block.width % 2 == 0 && block.values_stride % 2 == 0 &&
                      reinterpret_cast<uintptr_t>(block.values) % kPairAlignment == 0;
  }
  if (base.defined()) a.base = keep_contiguous(base);
  a.first_bias = keep_contiguous(n.first_bias);
  a.hidden_layers = int(n.norm_weights.size());
  for (int k = 0; k < a.hidden_layers; ++k) {
    a.norm_weights[k] = keep_contiguous(n.norm_weights[k]);
    a.norm_biases[k] = keep_contiguous(n.norm_biases[k]);
    if (k == 0) continue;
    a.hidden_weights[k - 1] = keep_contiguous(n.hidden_weights[k - 1]);
    a.hidden_biases[k - 1] = keep_contiguous(n.hidden_biases[k - 1]);
  }
  a.output_weight = keep_contiguous(n.output_weight);
  a.output_bias = keep_contiguous(n.output_bias);
  a.outputs = int(n.output_weight.size(0));
  a.epsilon = float(n.epsilon);
  a.rows = inputs[0].size(0);
  at::Tensor out = at::empty({a.rows, a.outputs}, n.output_weight.options());
  a.out = out.data_ptr<float>();
  cuda::forward(a, out.device());
  return out;
#else
  (void)inputs, (void)base, (void)n;
  TORCH_CHECK(false, "mlp_inference: this build has no CUDA backend");
#endif
}

// ---- the dispatcher op (ops/registration.h): inference only, so its Autograd kernel refuses a gradient ----

constexpr const char* kNetworkSchema =
    "mlp_inference(Tensor[] inputs, Tensor? base, Tensor[] input_weights, Tensor first_bias, Tensor[] hidden_weights, "
    "Tensor[] hidden_biases, Tensor[] norm_weights, Tensor[] norm_biases, Tensor output_weight, Tensor output_bias, "
    "int groups, float epsilon) -> Tensor";
using NetworkSignature = at::Tensor(at::TensorList, const ops::OptionalTensor&, at::TensorList, const at::Tensor&,
                                    at::TensorList, at::TensorList, at::TensorList, at::TensorList, const at::Tensor&,
                                    const at::Tensor&, int64_t, double);
#define SFGS_MLP_INFERENCE_PARAMETERS                                                                                 \
  at::TensorList inputs, const ops::OptionalTensor &base, at::TensorList input_weights, const at::Tensor &first_bias, \
      at::TensorList hidden_weights, at::TensorList hidden_biases, at::TensorList norm_weights,                       \
      at::TensorList norm_biases, const at::Tensor &output_weight, const at::Tensor &output_bias, int64_t groups,     \
      double epsilon

const c10::TypedOperatorHandle<NetworkSignature>& network_op() {
  static const auto handle = ops::find_op<NetworkSignature>("sfgs::mlp_inference");
  return handle;
}

Network network_of(at::TensorList input_weights, const at::Tensor& first_bias, at::TensorList hidden_weights,
                   at::TensorList hidden_biases, at::TensorList norm_weights, at::TensorList norm_biases,
                   const at::Tensor& output_weight, const at::Tensor& output_bias, int64_t groups, double epsilon) {
  return Network{input_weights.vec(),
                 first_bias,
                 hidden_weights.vec(),
                 hidden_biases.vec(),
                 norm_weights.vec(),
                 norm_biases.vec(),
                 output_weight,
                 output_bias,
                 groups,
                 epsilon};
}

#define SFGS_MLP_INFERENCE_NETWORK                                                                               \
  network_of(input_weights, first_bias, hidden_weights, hidden_biases, norm_weights, norm_biases, output_weight, \
             output_bias, groups, epsilon)

at::Tensor network_cpu_kernel(SFGS_MLP_INFERENCE_PARAMETERS) {
  return reference(inputs.vec(), base.value_or(at::Tensor()), SFGS_MLP_INFERENCE_NETWORK);
}

#if defined(SFGS_WITH_CUDA)
at::Tensor network_cuda_kernel(SFGS_MLP_INFERENCE_PARAMETERS) {
  const std::vector<at::Tensor> blocks = inputs.vec();
  const Network n = SFGS_MLP_INFERENCE_NETWORK;
  const at::Tensor b = base.value_or(at::Tensor());
  check_network(blocks, b, n);
  return fuses(blocks, n) ? fused_network(blocks, b, n) : reference(blocks, b, n);
}
#endif

at::Tensor network_meta_kernel(SFGS_MLP_INFERENCE_PARAMETERS) {
  const std::vector<at::Tensor> blocks = inputs.vec();
  check_network(blocks, base.value_or(at::Tensor()), SFGS_MLP_INFERENCE_NETWORK);
  return at::empty({blocks[0].size(0), output_weight.size(0)}, output_weight.options());
}

at::Tensor network_autograd_kernel(SFGS_MLP_INFERENCE_PARAMETERS) {
  if (at::GradMode::is_enabled()) {
    bool needs_gradient = base.has_value() && base->defined() && base->requires_grad();
    for (const at::TensorList list : {inputs, input_weights, hidden_weights, hidden_biases, norm_weights, norm_biases})
      for (const at::Tensor& t : list) needs_gradient = needs_gradient || (t.defined() && t.requires_grad());
    for (const at::Tensor* t : {&first_bias, &output_weight, &output_bias})
      needs_gradient = needs_gradient || (t->defined() && t->requires_grad());
    TORCH_CHECK(!needs_gradient,
                "mlp_inference: inference only; use mlp_inference::reference where a gradient is "
                "needed (or run under torch::NoGradGuard)");
  }
  const at::AutoDispatchBelowADInplaceOrView below_autograd;
  return network_op().call(inputs, base, input_weights, first_bias, hidden_weights, hidden_biases, norm_weights,
                           norm_biases, output_weight, output_bias, groups, epsilon);
}

#undef SFGS_MLP_INFERENCE_NETWORK
#undef SFGS_MLP_INFERENCE_PARAMETERS

}  // namespace

at::Tensor reference(const std::vector<at::Tensor>& inputs, const at::Tensor& base, const Network& n) {
  check_network(inputs, base, n);
  at::Tensor first = at::linear(inputs[0], n.input_weights[0]);
  for (size_t b = 1; b < inputs.size(); ++b) first = first + at::linear(inputs[b], n.input_weights[b]);
  if (base.defined()) first = first + base;
  at::Tensor x = group_norm::group_norm_relu_reference(first, n.first_bias, n.norm_weights[0], n.norm_biases[0],
                                                       n.groups, n.epsilon);
  for (size_t k = 1; k < n.norm_weights.size(); ++k)
    x = group_norm::group_norm_relu_reference(at::linear(x, n.hidden_weights[k - 1]), n.hidden_biases[k - 1],
                                              n.norm_weights[k], n.norm_biases[k], n.groups, n.epsilon);
  return at::linear(x, n.output_weight, n.output_bias);
}

bool fuses(const std::vector<at::Tensor>& inputs, const Network& n) {
#if defined(SFGS_WITH_CUDA)
  // Only the shape questions: the op validates the network itself (and fuses() must not fail on a bad one).
  if (n.input_weights.empty() || inputs.size() > kFusedMaxInputs) return false;
  int64_t width = 0;
  for (const at::Tensor& b : n.input_weights) {
    if (!b.defined() || b.dim() != 2) return false;
    width += b.size(1);
  }
  const at::Tensor& w = n.input_weights[0];
  if (!w.is_cuda() || w.scalar_type() != at::kFloat || w.size(0) != kFusedWidth || n.groups != kFusedGroups)
    return false;
  if (n.norm_weights.empty() || n.norm_weights.size() > kFusedMaxHiddenLayers || !n.output_weight.defined() ||
      n.output_weight.dim() != 2)
    return false;
  return width <= kFusedMaxInputWidth && n.output_weight.size(0) <= kFusedMaxOutputs &&
         cuda::fits(int(n.norm_weights.size()), int(width), w.device());
#else
  (void)inputs, (void)n;
  return false;
#endif
}

at::Tensor run(const std::vector<at::Tensor>& inputs, const at::Tensor& base, const Network& n) {
  check_network(inputs, base, n);
  return network_op().call(inputs, ops::optional_tensor(base), n.input_weights, n.first_bias, n.hidden_weights,
                           n.hidden_biases, n.norm_weights, n.norm_biases, n.output_weight, n.output_bias, n.groups,
                           n.epsilon);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) { m.def(kNetworkSchema); }
TORCH_LIBRARY_IMPL(sfgs, CPU, m) { m.impl("mlp_inference", TORCH_FN(network_cpu_kernel)); }
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) { m.impl("mlp_inference", TORCH_FN(network_cuda_kernel)); }
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) { m.impl("mlp_inference", TORCH_FN(network_meta_kernel)); }
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("mlp_inference", TORCH_FN(network_autograd_kernel)); }

}  // namespace sfgs::mlp_inference
