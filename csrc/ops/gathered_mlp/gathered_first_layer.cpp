// The gathered first layer as a training op: validation at its boundary, the backend by device, and its one autograd
// node.
#include "ops/gathered_mlp/gathered_mlp.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "common/tensor_description.h"
#include "ops/gathered_mlp/backend.h"
#include "ops/linear/linear.h"

namespace sfgs::gathered_mlp {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

template <typename T>
void forward_as(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups,
                const at::Tensor& out) {
  const FirstLayerArrays<T> a{row_inputs.data_ptr<T>(),
                              group_inputs.data_ptr<T>(),
                              groups.data_ptr<int64_t>(),
                              out.data_ptr<T>(),
                              out.size(0),
                              out.size(1),
                              group_inputs.size(0)};
  if (out.is_cuda())
    cuda::first_layer_forward(a, out.device());
  else
    cpu::first_layer_forward(a);
}

template <typename T>
void backward_as(const at::Tensor& out, const at::Tensor& grad_out, const at::Tensor& groups,
                 const at::Tensor& grad_rows, const at::Tensor& group_partials, int64_t group_count) {
  const FirstLayerGradientArrays<T> a{out.data_ptr<T>(),
                                      grad_out.data_ptr<T>(),
                                      groups.data_ptr<int64_t>(),
                                      grad_rows.data_ptr<T>(),
                                      group_partials.data_ptr<T>(),
                                      out.size(0),
                                      out.size(1),
                                      group_count,
                                      group_partials.size(0)};
  if (out.is_cuda())
    cuda::first_layer_backward(a, out.device());
  else
    cpu::first_layer_backward(a);
}

// One node: row_inputs and group_inputs (contiguous) and groups (int64, no gradient) in; the activation out, kept
// for the backward, whose ReLU mask it is.
class GatheredFirstLayerFunction : public torch::autograd::Function<GatheredFirstLayerFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                            const at::Tensor& groups) {
    const at::Tensor out = at::empty_like(row_inputs);
    if (out.numel() > 0) {
      if (out.scalar_type() == at::kDouble)
        forward_as<double>(row_inputs, group_inputs, groups, out);
      else
        forward_as<float>(row_inputs, group_inputs, groups, out);
    }
    ctx->save_for_backward({out, groups});
    ctx->saved_data["group_count"] = group_inputs.size(0);
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const at::Tensor& out = saved[0];
    const at::Tensor& groups = saved[1];
    const int64_t group_count = ctx->saved_data["group_count"].toInt(), rows = out.size(0), width = out.size(1);
    if (out.numel() == 0) return {at::zeros_like(out), at::zeros({group_count, width}, out.options()), at::Tensor()};
    const at::Tensor grad_out = grads[0].contiguous();
    const at::Tensor grad_rows = at::empty_like(out);
    const int64_t partial_rows =
        out.is_cuda() ? cuda::first_layer_partial_rows(rows, out.device()) : cpu::first_layer_partial_rows(rows);
    const at::Tensor group_partials = at::empty({partial_rows, group_count * width}, out.options());
    if (out.scalar_type() == at::kDouble)
      backward_as<double>(out, grad_out, groups, grad_rows, group_partials, group_count);
    else
      backward_as<float>(out, grad_out, groups, grad_rows, group_partials, group_count);
    return {grad_rows, linear::column_sum(group_partials).view({group_count, width}), at::Tensor()};
  }
};

// The CPU backend takes only groups in [0, group_count): the first that is not is an error naming it and its row.
void check_groups_in_range(const at::Tensor& groups, int64_t group_count) {
  const int64_t* group = groups.data_ptr<int64_t>();
  for (int64_t row = 0; row < groups.numel(); ++row)
    TORCH_CHECK(valid_group(group[row], group_count), "gathered_first_layer: groups must lie in [0, ", group_count,
                "), got ", group[row], " at row ", row);
}

}  // namespace

at::Tensor gathered_first_layer(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                const at::Tensor& groups) {
  TORCH_CHECK(row_inputs.defined() && row_inputs.dim() == 2 && is_float_or_double(row_inputs),
              "gathered_first_layer: row_inputs must be a float or double (N, H) tensor, got ", describe(row_inputs));
  TORCH_CHECK(row_inputs.is_cpu() || row_inputs.is_cuda(),
              "gathered_first_layer: tensors must be on the CPU or a CUDA device, got ", describe(row_inputs));
  const int64_t n = row_inputs.size(0), h = row_inputs.size(1);
  const at::ScalarType dtype = row_inputs.scalar_type();
  const at::Device device = row_inputs.device();
  TORCH_CHECK(group_inputs.defined() && group_inputs.dim() == 2 && group_inputs.size(0) >= 1 &&
                  group_inputs.size(1) == h && group_inputs.scalar_type() == dtype && group_inputs.device() == device,
              "gathered_first_layer: group_inputs must be a ", dtype, " (G, ", h, ") tensor with G >= 1 on ", device,
              ", got ", describe(group_inputs));
  TORCH_CHECK(groups.defined() && groups.dim() == 1 && groups.size(0) == n && groups.scalar_type() == at::kLong &&
                  groups.device() == device,
              "gathered_first_layer: groups must be an int64 (", n, ") tensor on ", device, ", got ", describe(groups));
  if (row_inputs.is_cuda()) TORCH_CHECK(cuda::available(), "gathered_first_layer: this build has no CUDA backend");
  const at::Tensor group_ids = groups.contiguous();
  if (group_ids.is_cpu()) check_groups_in_range(group_ids, group_inputs.size(0));
  return GatheredFirstLayerFunction::apply(row_inputs.contiguous(), group_inputs.contiguous(), group_ids);
}

at::Tensor gathered_first_layer_reference(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                          const at::Tensor& groups) {
  return at::relu(row_inputs + at::embedding(group_inputs, groups));
}

}  // namespace sfgs::gathered_mlp
