#include "ops/gathered_mlp/gathered_mlp.h"

#include <limits>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/gathered_mlp/backend.h"
#include "ops/registration.h"

namespace sfgs::gathered_mlp {
namespace {

// Shapes, dtypes and devices; returns (H, O).
std::pair<int64_t, int64_t> check_inputs(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                         const at::Tensor& groups, const GatheredMlpWeights& w) {
  TORCH_CHECK(row_inputs.defined() && row_inputs.dim() == 2 && at::isFloatingType(row_inputs.scalar_type()),
              "gathered_mlp: row_inputs must be a floating (N, H) tensor, got ", describe(row_inputs));
  const int64_t n = row_inputs.size(0), h = row_inputs.size(1);
  TORCH_CHECK(w.hidden_weight.defined() && at::isFloatingType(w.hidden_weight.scalar_type()) &&
                  w.hidden_weight.sizes() == at::IntArrayRef({h, h}),
              "gathered_mlp: hidden_weight must be a floating (", h, ", ", h, ") tensor, got ",
              describe(w.hidden_weight));
  const at::ScalarType dtype = w.hidden_weight.scalar_type();
  const at::Device device = row_inputs.device();
  const auto check = [&](const at::Tensor& t, const char* name, at::IntArrayRef shape) {
    check_tensor(t, std::string("gathered_mlp: ") + name, shape, dtype, device);
  };
  TORCH_CHECK(w.output_weight.defined() && w.output_weight.dim() == 2 && w.output_weight.size(0) > 0,
              "gathered_mlp: output_weight must be an (O, ", h, ") tensor with O >= 1, got ",
              describe(w.output_weight));
  const int64_t o = w.output_weight.size(0);
  check(w.hidden_weight, "hidden_weight", {h, h});
  check(w.hidden_bias, "hidden_bias", {h});
  check(w.output_weight, "output_weight", {o, h});
  check(w.output_bias, "output_bias", {o});
  TORCH_CHECK(
      group_inputs.defined() && group_inputs.dim() == 2 && group_inputs.size(1) == h && group_inputs.size(0) > 0,
      "gathered_mlp: group_inputs must be a (G, ", h, ") tensor with G >= 1, got ", describe(group_inputs));
  check(group_inputs, "group_inputs", {group_inputs.size(0), h});
  TORCH_CHECK(groups.defined() && groups.dim() == 1 && groups.size(0) == n &&
                  (groups.scalar_type() == at::kInt || groups.scalar_type() == at::kLong) && groups.device() == device,
              "gathered_mlp: groups must be an int32 or int64 (", n, ") tensor on ", device, ", got ",
              describe(groups));
  return {h, o};
}

// The fused kernel (fuses() holds): the rows' share and the hidden weights in half, the groups int32.
at::Tensor fused_mlp(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups,
                     const GatheredMlpWeights& w) {
#if defined(SFGS_WITH_CUDA)
  const at::Tensor rows = row_inputs.to(at::kHalf).contiguous();
  const at::Tensor group_rows = group_inputs.contiguous();
  const at::Tensor group_ids = groups.to(at::kInt).contiguous();
  const at::Tensor hidden_weight = w.hidden_weight.to(at::kHalf).contiguous();
  const at::Tensor hidden_bias = w.hidden_bias.contiguous(), output_weight = w.output_weight.contiguous();
  const at::Tensor output_bias = w.output_bias.contiguous();
  at::Tensor out = at::empty({rows.size(0), output_weight.size(0)}, group_rows.options());
  GatheredMlpArrays arrays{};
  arrays.row_inputs = reinterpret_cast<const uint16_t*>(rows.data_ptr<at::Half>());
  arrays.group_inputs = group_rows.data_ptr<float>();
  arrays.groups = group_ids.data_ptr<int32_t>();
  arrays.group_count = static_cast<int32_t>(group_rows.size(0));
  arrays.hidden_weight = reinterpret_cast<const uint16_t*>(hidden_weight.data_ptr<at::Half>());
  arrays.hidden_bias = hidden_bias.data_ptr<float>();
  arrays.output_weight = output_weight.data_ptr<float>();
  arrays.output_bias = output_bias.data_ptr<float>();
  arrays.rows = rows.size(0);
  arrays.outputs = static_cast<int>(output_weight.size(0));
  arrays.out = out.data_ptr<float>();
  cuda::forward(arrays, out.device());
  return out;
#else
  (void)row_inputs, (void)group_inputs, (void)groups, (void)w;
  TORCH_CHECK(false, "gathered_mlp: this build has no CUDA backend");
#endif
}

// ---- the dispatcher op (ops/registration.h): inference only, so its Autograd kernel refuses a gradient ----

constexpr const char* kMlpSchema =
    "gathered_mlp(Tensor row_inputs, Tensor group_inputs, Tensor groups, Tensor hidden_weight, Tensor hidden_bias, "
    "Tensor output_weight, Tensor output_bias) -> Tensor";
using MlpSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                const at::Tensor&, const at::Tensor&, const at::Tensor&);
#define SFGS_GATHERED_MLP_PARAMETERS                                                                   \
  const at::Tensor &row_inputs, const at::Tensor &group_inputs, const at::Tensor &groups,              \
      const at::Tensor &hidden_weight, const at::Tensor &hidden_bias, const at::Tensor &output_weight, \
      const at::Tensor &output_bias
#define SFGS_GATHERED_MLP_ARGUMENTS \
  row_inputs, group_inputs, groups, hidden_weight, hidden_bias, output_weight, output_bias

const c10::TypedOperatorHandle<MlpSignature>& mlp_op() {
  static const auto handle = ops::find_op<MlpSignature>("sfgs::gathered_mlp");
  return handle;
}

at::Tensor mlp_cpu_kernel(SFGS_GATHERED_MLP_PARAMETERS) {
  return gathered_mlp_reference(row_inputs, group_inputs, groups,
                                {hidden_weight, hidden_bias, output_weight, output_bias});
}

#if defined(SFGS_WITH_CUDA)
at::Tensor mlp_cuda_kernel(SFGS_GATHERED_MLP_PARAMETERS) {
  const GatheredMlpWeights w{hidden_weight, hidden_bias, output_weight, output_bias};
  check_inputs(row_inputs, group_inputs, groups, w);
  return fuses(row_inputs, w) ? fused_mlp(row_inputs, group_inputs, groups, w)
                              : gathered_mlp_reference(row_inputs, group_inputs, groups, w);
}
#endif

at::Tensor mlp_meta_kernel(SFGS_GATHERED_MLP_PARAMETERS) {
  const int64_t o =
      check_inputs(row_inputs, group_inputs, groups, {hidden_weight, hidden_bias, output_weight, output_bias}).second;
  return at::empty({row_inputs.size(0), o}, group_inputs.options());
}

at::Tensor mlp_autograd_kernel(SFGS_GATHERED_MLP_PARAMETERS) {
  bool needs_gradient = false;
  for (const at::Tensor* t : {&row_inputs, &group_inputs, &hidden_weight, &hidden_bias, &output_weight, &output_bias})
    needs_gradient = needs_gradient || (t->defined() && t->requires_grad());
  TORCH_CHECK(!(at::GradMode::is_enabled() && needs_gradient),
              "gathered_mlp: inference only; use gathered_mlp_reference where a gradient is needed "
              "(or run under torch::NoGradGuard)");
  const at::AutoDispatchBelowADInplaceOrView below_autograd;
  return mlp_op().call(SFGS_GATHERED_MLP_ARGUMENTS);
}

}  // namespace

at::Tensor gathered_mlp_reference(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                  const at::Tensor& groups, const GatheredMlpWeights& w) {
  check_inputs(row_inputs, group_inputs, groups, w);
  const int64_t group_count = group_inputs.size(0);
  at::Tensor index = groups.to(at::kLong);
  at::Tensor outside;  // rows whose group is out of range, off the CPU (checking would read the device)
  if (index.is_cpu()) {
    TORCH_CHECK(values_within(index, 0, group_count), "gathered_mlp: groups must lie in [0, ", group_count, ")");
  } else {
    outside = (index < 0) | (index >= group_count);
    index = index.clamp(0, group_count - 1);
  }
  at::Tensor first = row_inputs.to(group_inputs.scalar_type()) + group_inputs.index_select(0, index);
  if (outside.defined()) first = first.masked_fill(outside.unsqueeze(1), std::numeric_limits<double>::quiet_NaN());
  const at::Tensor hidden = at::relu(at::linear(at::relu(first), w.hidden_weight, w.hidden_bias));
  return at::linear(hidden, w.output_weight, w.output_bias);
}

bool fuses(const at::Tensor& row_inputs, const GatheredMlpWeights& w) {
#if defined(SFGS_WITH_CUDA)
  return row_inputs.defined() && row_inputs.is_cuda() && row_inputs.dim() == 2 && row_inputs.size(1) == kFusedWidth &&
         w.output_weight.defined() && w.output_weight.dim() == 2 && w.output_weight.size(0) <= kFusedMaxOutputs &&
         w.hidden_weight.defined() && w.hidden_weight.scalar_type() == at::kFloat;
#else
  (void)row_inputs, (void)w;
  return false;
#endif
}

at::Tensor gathered_mlp(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups,
                        const GatheredMlpWeights& w) {
  check_inputs(row_inputs, group_inputs, groups, w);
  return mlp_op().call(row_inputs, group_inputs, groups, w.hidden_weight, w.hidden_bias, w.output_weight,
                       w.output_bias);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) { m.def(kMlpSchema); }
TORCH_LIBRARY_IMPL(sfgs, CPU, m) { m.impl("gathered_mlp", TORCH_FN(mlp_cpu_kernel)); }
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) { m.impl("gathered_mlp", TORCH_FN(mlp_cuda_kernel)); }
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) { m.impl("gathered_mlp", TORCH_FN(mlp_meta_kernel)); }
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("gathered_mlp", TORCH_FN(mlp_autograd_kernel)); }

}  // namespace sfgs::gathered_mlp
#undef SFGS_GATHERED_MLP_PARAMETERS
#undef SFGS_GATHERED_MLP_ARGUMENTS
