// The linear layer and the column sum: validation at their boundary and their dispatcher registration
// (ops/registration.h). The layer's CPU and CUDA kernels are LibTorch's matrix product with the bias in its epilogue;
// its Autograd kernel is its one node, whose bias gradient is the column sum; the column sum's CUDA kernel is sfgs's
// deterministic two-pass reduction.
#include "ops/linear/linear.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/linear/backend.h"
#include "ops/registration.h"

namespace sfgs::linear {
namespace {

using ops::OptionalTensor;
using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

constexpr const char* kLinearSchema = "linear(Tensor x, Tensor weight, Tensor? bias) -> Tensor";
constexpr const char* kColumnSumSchema = "column_sum(Tensor rows) -> Tensor";
using LinearSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const OptionalTensor&);
using ColumnSumSignature = at::Tensor(const at::Tensor&);

const c10::TypedOperatorHandle<LinearSignature>& linear_op() {
  static const auto handle = ops::find_op<LinearSignature>("sfgs::linear");
  return handle;
}
const c10::TypedOperatorHandle<ColumnSumSignature>& column_sum_op() {
  static const auto handle = ops::find_op<ColumnSumSignature>("sfgs::column_sum");
  return handle;
}

void check_linear(const at::Tensor& x, const at::Tensor& weight, const OptionalTensor& bias) {
  TORCH_CHECK(x.defined() && x.dim() == 2 && at::isFloatingType(x.scalar_type()),
              "linear: x must be a floating (N, I) tensor, got ", describe(x));
  TORCH_CHECK(weight.defined() && weight.dim() == 2 && weight.size(1) == x.size(1) &&
                  weight.scalar_type() == x.scalar_type() && weight.device() == x.device(),
              "linear: weight must be a ", x.scalar_type(), " (O, ", x.size(1), ") tensor on ", x.device(), ", got ",
              describe(weight));
  TORCH_CHECK(!bias.has_value() || (bias->dim() == 1 && bias->size(0) == weight.size(0) &&
                                    bias->scalar_type() == x.scalar_type() && bias->device() == x.device()),
              "linear: bias must be a ", x.scalar_type(), " (", weight.size(0), ") tensor on ", x.device(), ", got ",
              describe(bias.value_or(at::Tensor())));
}

void check_rows(const at::Tensor& rows) {
  TORCH_CHECK(rows.defined() && rows.dim() == 2 && at::isFloatingType(rows.scalar_type()),
              "column_sum: rows must be a floating (R, C) tensor, got ", describe(rows));
}

at::Tensor linear_kernel(const at::Tensor& x, const at::Tensor& weight, const OptionalTensor& bias) {
  check_linear(x, weight, bias);
  return bias.has_value() ? at::addmm(*bias, x, weight.t()) : at::mm(x, weight.t());
}

at::Tensor linear_meta(const at::Tensor& x, const at::Tensor& weight, const OptionalTensor& bias) {
  check_linear(x, weight, bias);
  return at::empty({x.size(0), weight.size(0)}, x.options());
}

at::Tensor column_sum_cpu(const at::Tensor& rows) {
  check_rows(rows);
  return rows.sum(0);
}

#if defined(SFGS_WITH_CUDA)
at::Tensor column_sum_cuda(const at::Tensor& rows) {
  check_rows(rows);
  if (!is_float_or_double(rows)) return rows.sum(0);
  return cuda::column_sum(rows.contiguous());
}
#endif

at::Tensor column_sum_meta(const at::Tensor& rows) {
  check_rows(rows);
  return at::empty({rows.size(1)}, rows.options());
}

// The layer's one node: x, weight and bias in, x weight^T + bias out.
class LinearFunction : public torch::autograd::Function<LinearFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& weight,
                            const OptionalTensor& bias) {
    ctx->save_for_backward({x, weight});
    ctx->saved_data["bias"] = bias.has_value();
    const at::AutoDispatchBelowADInplaceOrView below_autograd;
    return linear_op().call(x, weight, bias);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const at::Tensor& x = saved[0];
    const at::Tensor& weight = saved[1];
    const at::Tensor grad = grads[0].contiguous();  // materialised: zeros where the output had no gradient
    const at::Tensor grad_x = ctx->needs_input_grad(0) ? grad.mm(weight) : at::Tensor();
    const at::Tensor grad_weight = ctx->needs_input_grad(1) ? grad.t().mm(x) : at::Tensor();
    const bool bias = ctx->saved_data["bias"].toBool();
    const at::Tensor grad_bias = bias && ctx->needs_input_grad(2) ? column_sum_op().call(grad) : at::Tensor();
    return {grad_x, grad_weight, grad_bias};
  }
};

at::Tensor linear_autograd(const at::Tensor& x, const at::Tensor& weight, const OptionalTensor& bias) {
  return LinearFunction::apply(x, weight, bias);
}

}  // namespace

at::Tensor linear(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias) {
  const OptionalTensor optional_bias = ops::optional_tensor(bias);
  check_linear(x, weight, optional_bias);
  return linear_op().call(x, weight, optional_bias);
}

at::Tensor column_sum(const at::Tensor& rows) {
  check_rows(rows);
  return column_sum_op().call(rows);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kLinearSchema);
  m.def(kColumnSumSchema);
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("linear", TORCH_FN(linear_kernel));
  m.impl("column_sum", TORCH_FN(column_sum_cpu));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("linear", TORCH_FN(linear_kernel));
  m.impl("column_sum", TORCH_FN(column_sum_cuda));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("linear", TORCH_FN(linear_meta));
  m.impl("column_sum", TORCH_FN(column_sum_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("linear", TORCH_FN(linear_autograd)); }

}  // namespace sfgs::linear
