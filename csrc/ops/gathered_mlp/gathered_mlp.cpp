#include "ops/gathered_mlp/gathered_mlp.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "common/tensor_description.h"
#include "ops/gathered_mlp/backend.h"

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
    TORCH_CHECK(t.defined() && t.sizes() == shape && t.scalar_type() == dtype && t.device() == device,
                "gathered_mlp: ", name, " must be a ", dtype, " tensor of shape ", shape, " on ", device, ", got ",
                describe(t));
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

}  // namespace

at::Tensor gathered_mlp_reference(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                  const at::Tensor& groups, const GatheredMlpWeights& w) {
  check_inputs(row_inputs, group_inputs, groups, w);
  const at::Tensor index = groups.to(at::kLong);
  if (index.is_cpu() && index.numel() > 0)
    TORCH_CHECK(index.min().item<int64_t>() >= 0 && index.max().item<int64_t>() < group_inputs.size(0),
                "gathered_mlp: groups must lie in [0, ", group_inputs.size(0), ")");
  const at::Tensor first = row_inputs.to(group_inputs.scalar_type()) + group_inputs.index_select(0, index);
  const at::Tensor hidden = at::relu(at::linear(at::relu(first), w.hidden_weight, w.hidden_bias));
  return at::linear(hidden, w.output_weight, w.output_bias);
}

bool fuses(const at::Tensor& row_inputs, const GatheredMlpWeights& w) {
  return cuda::available() && row_inputs.defined() && row_inputs.is_cuda() && row_inputs.dim() == 2 &&
         row_inputs.size(1) == kFusedWidth && w.output_weight.defined() && w.output_weight.dim() == 2 &&
         w.output_weight.size(0) <= kFusedMaxOutputs && w.hidden_weight.scalar_type() == at::kFloat;
}

at::Tensor gathered_mlp(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups,
                        const GatheredMlpWeights& w) {
  const int64_t o = check_inputs(row_inputs, group_inputs, groups, w).second;
  bool needs_gradient = at::GradMode::is_enabled() && (row_inputs.requires_grad() || group_inputs.requires_grad());
  for (const at::Tensor* t : {&w.hidden_weight, &w.hidden_bias, &w.output_weight, &w.output_bias})
    needs_gradient = needs_gradient || (at::GradMode::is_enabled() && t->requires_grad());
  TORCH_CHECK(!needs_gradient,
              "gathered_mlp: inference only; use gathered_mlp_reference where a gradient is needed "
              "(or run under torch::NoGradGuard)");
  if (!fuses(row_inputs, w)) return gathered_mlp_reference(row_inputs, group_inputs, groups, w);

  const at::Tensor rows = row_inputs.to(at::kHalf).contiguous();
  const at::Tensor group_rows = group_inputs.contiguous();
  const at::Tensor group_ids = groups.to(at::kInt).contiguous();
  const at::Tensor hidden_weight = w.hidden_weight.to(at::kHalf).contiguous();
  const at::Tensor hidden_bias = w.hidden_bias.contiguous(), output_weight = w.output_weight.contiguous();
  const at::Tensor output_bias = w.output_bias.contiguous();
  at::Tensor out = at::empty({rows.size(0), o}, group_rows.options());
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
  arrays.outputs = static_cast<int>(o);
  arrays.out = out.data_ptr<float>();
  cuda::forward(arrays, out.device());
  return out;
}

}  // namespace sfgs::gathered_mlp
