// The gathered first layer as a training op: validation at its boundary and its dispatcher registration
// (ops/registration.h): CPU and CUDA kernels that route to the backend by device, Meta kernels, one autograd node.
#include "ops/gathered_mlp/gathered_mlp.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/gathered_mlp/backend.h"
#include "ops/linear/linear.h"
#include "ops/registration.h"

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
#if defined(SFGS_WITH_CUDA)
  if (out.is_cuda()) return cuda::first_layer_forward(a, out.device());
#endif
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
#if defined(SFGS_WITH_CUDA)
  if (out.is_cuda()) return cuda::first_layer_backward(a, out.device());
#endif
  cpu::first_layer_backward(a);
}

// The CPU backend takes only groups in [0, group_count): the first that is not is an error naming it and its row.
void check_groups_in_range(const at::Tensor& groups, int64_t group_count) {
  const int64_t* group = groups.data_ptr<int64_t>();
  for (int64_t row = 0; row < groups.numel(); ++row)
    TORCH_CHECK(valid_group(group[row], group_count), "gathered_first_layer: groups must lie in [0, ", group_count,
                "), got ", group[row], " at row ", row);
}

// The rows (N, H); `on_meta`: a Meta kernel's check, which takes meta tensors too.
void check_rows(const at::Tensor& rows, bool on_meta) {
  TORCH_CHECK(rows.defined() && rows.dim() == 2 && is_float_or_double(rows),
              "gathered_first_layer: row_inputs must be a float or double (N, H) tensor, got ", describe(rows));
  TORCH_CHECK(rows.is_cpu() || rows.is_cuda() || (on_meta && rows.is_meta()),
              "gathered_first_layer: tensors must be on the CPU or a CUDA device, got ", describe(rows));
  if (rows.is_cuda()) TORCH_CHECK(ops::kBuiltWithCuda, "gathered_first_layer: this build has no CUDA backend");
}

// The rows' groups in [0, group_count): the CUDA kernel turns one out of range into a NaN row (no host read); the
// CPU's are read here.
void check_groups(const at::Tensor& groups, const at::Tensor& rows, int64_t group_count) {
  TORCH_CHECK(groups.defined() && groups.dim() == 1 && groups.size(0) == rows.size(0) &&
                  groups.scalar_type() == at::kLong && groups.device() == rows.device(),
              "gathered_first_layer: groups must be an int64 (", rows.size(0), ") tensor on ", rows.device(), ", got ",
              describe(groups));
  if (groups.is_cpu()) check_groups_in_range(groups.contiguous(), group_count);
}

void check_inputs(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups,
                  bool on_meta = false) {
  check_rows(row_inputs, on_meta);
  TORCH_CHECK(group_inputs.defined() && group_inputs.dim() == 2 && group_inputs.size(0) >= 1 &&
                  group_inputs.size(1) == row_inputs.size(1) &&
                  group_inputs.scalar_type() == row_inputs.scalar_type() &&
                  group_inputs.device() == row_inputs.device(),
              "gathered_first_layer: group_inputs must be a ", row_inputs.scalar_type(), " (G, ", row_inputs.size(1),
              ") tensor with G >= 1 on ", row_inputs.device(), ", got ", describe(group_inputs));
  check_groups(groups, row_inputs, group_inputs.size(0));
}

// ---- the dispatcher ops (ops/registration.h) ----

constexpr const char* kForwardSchema =
    "gathered_first_layer(Tensor row_inputs, Tensor group_inputs, Tensor groups) -> Tensor";
constexpr const char* kBackwardSchema =
    "gathered_first_layer_backward(Tensor grad, Tensor out, Tensor groups, int group_count) "
    "-> (Tensor grad_row_inputs, Tensor grad_group_inputs)";
using ForwardSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&);
using BackwardSignature = std::tuple<at::Tensor, at::Tensor>(const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                                             int64_t);

const c10::TypedOperatorHandle<ForwardSignature>& forward_op() {
  static const auto handle = ops::find_op<ForwardSignature>("sfgs::gathered_first_layer");
  return handle;
}
const c10::TypedOperatorHandle<BackwardSignature>& backward_op() {
  static const auto handle = ops::find_op<BackwardSignature>("sfgs::gathered_first_layer_backward");
  return handle;
}

at::Tensor forward_kernel(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups) {
  check_inputs(row_inputs, group_inputs, groups);
  const at::Tensor rows = row_inputs.contiguous(), group_rows = group_inputs.contiguous(), ids = groups.contiguous();
  const at::Tensor out = at::empty_like(rows);
  if (out.numel() == 0) return out;
  if (out.scalar_type() == at::kDouble)
    forward_as<double>(rows, group_rows, ids, out);
  else
    forward_as<float>(rows, group_rows, ids, out);
  return out;
}

at::Tensor forward_meta(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups) {
  check_inputs(row_inputs, group_inputs, groups, /*on_meta=*/true);
  return at::empty_like(row_inputs, at::MemoryFormat::Contiguous);
}

void check_backward_inputs(const at::Tensor& grad, const at::Tensor& out, const at::Tensor& groups, int64_t group_count,
                           bool on_meta = false) {
  TORCH_CHECK(group_count >= 1, "gathered_first_layer_backward: group_count must be at least 1, got ", group_count);
  check_rows(out, on_meta);
  check_groups(groups, out, group_count);
  TORCH_CHECK(grad.sizes() == out.sizes() && grad.scalar_type() == out.scalar_type() && grad.device() == out.device(),
              "gathered_first_layer_backward: grad must be like the output (", describe(out), "), got ",
              describe(grad));
}

std::tuple<at::Tensor, at::Tensor> backward_kernel(const at::Tensor& grad, const at::Tensor& out,
                                                   const at::Tensor& groups, int64_t group_count) {
  check_backward_inputs(grad, out, groups, group_count);
  const int64_t rows = out.size(0), width = out.size(1);
  if (out.numel() == 0) return {at::zeros_like(out), at::zeros({group_count, width}, out.options())};
  const at::Tensor activation = out.contiguous(), grad_out = grad.contiguous(), ids = groups.contiguous();
  const at::Tensor grad_rows = at::empty_like(activation);
#if defined(SFGS_WITH_CUDA)
  const int64_t partial_rows = activation.is_cuda() ? cuda::first_layer_partial_rows(rows, activation.device())
                                                    : cpu::first_layer_partial_rows(rows);
#else
  const int64_t partial_rows = cpu::first_layer_partial_rows(rows);
#endif
  const at::Tensor group_partials = at::empty({partial_rows, group_count * width}, activation.options());
  if (activation.scalar_type() == at::kDouble)
    backward_as<double>(activation, grad_out, ids, grad_rows, group_partials, group_count);
  else
    backward_as<float>(activation, grad_out, ids, grad_rows, group_partials, group_count);
  return {grad_rows, linear::column_sum(group_partials).view({group_count, width})};
}

std::tuple<at::Tensor, at::Tensor> backward_meta(const at::Tensor& grad, const at::Tensor& out,
                                                 const at::Tensor& groups, int64_t group_count) {
  check_backward_inputs(grad, out, groups, group_count, /*on_meta=*/true);
  return {at::empty_like(out, at::MemoryFormat::Contiguous), at::empty({group_count, out.size(1)}, out.options())};
}

// The op's one node: row_inputs and group_inputs in (groups: int64, no gradient); the activation out, kept for the
// backward, whose ReLU mask it is.
class GatheredFirstLayerFunction : public torch::autograd::Function<GatheredFirstLayerFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                            const at::Tensor& groups) {
    at::Tensor out;
    {
      const at::AutoDispatchBelowADInplaceOrView below_autograd;
      out = forward_op().call(row_inputs, group_inputs, groups);
    }
    ctx->save_for_backward({out, groups});
    ctx->saved_data["group_count"] = group_inputs.size(0);
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const auto [grad_rows, grad_groups] =
        backward_op().call(grads[0], saved[0], saved[1], ctx->saved_data["group_count"].toInt());
    return {grad_rows, grad_groups, at::Tensor()};
  }
};

at::Tensor autograd_kernel(const at::Tensor& row_inputs, const at::Tensor& group_inputs, const at::Tensor& groups) {
  return GatheredFirstLayerFunction::apply(row_inputs, group_inputs, groups);
}

}  // namespace

at::Tensor gathered_first_layer(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                const at::Tensor& groups) {
  check_inputs(row_inputs, group_inputs, groups);
  return forward_op().call(row_inputs, group_inputs, groups);
}

at::Tensor gathered_first_layer_reference(const at::Tensor& row_inputs, const at::Tensor& group_inputs,
                                          const at::Tensor& groups) {
  return at::relu(row_inputs + at::embedding(group_inputs, groups));
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kForwardSchema);
  m.def(kBackwardSchema);
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("gathered_first_layer", TORCH_FN(forward_kernel));
  m.impl("gathered_first_layer_backward", TORCH_FN(backward_kernel));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("gathered_first_layer", TORCH_FN(forward_kernel));
  m.impl("gathered_first_layer_backward", TORCH_FN(backward_kernel));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("gathered_first_layer", TORCH_FN(forward_meta));
  m.impl("gathered_first_layer_backward", TORCH_FN(backward_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("gathered_first_layer", TORCH_FN(autograd_kernel)); }

}  // namespace sfgs::gathered_mlp
