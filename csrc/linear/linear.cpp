// The linear layer: validation at its boundary and its one autograd node; the column sum by device.
#include "linear/linear.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "common/tensor_description.h"
#include "linear/backend.h"

namespace sfgs::linear {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// One node: x, weight and bias (an empty tensor for none: LibTorch 1.13's custom functions take no undefined
// inputs) in, x weight^T + bias out.
class LinearFunction : public torch::autograd::Function<LinearFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& weight,
                            const at::Tensor& bias_or_empty) {
    ctx->save_for_backward({x, weight});
    ctx->saved_data["bias"] = bias_or_empty.numel() > 0;
    return bias_or_empty.numel() > 0 ? at::addmm(bias_or_empty, x, weight.t()) : at::mm(x, weight.t());
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const at::Tensor& x = saved[0];
    const at::Tensor& weight = saved[1];
    const at::Tensor grad = grads[0].contiguous();  // materialised: zeros where the output had no gradient
    const at::Tensor grad_x = ctx->needs_input_grad(0) ? grad.mm(weight) : at::Tensor();
    const at::Tensor grad_weight = ctx->needs_input_grad(1) ? grad.t().mm(x) : at::Tensor();
    const bool bias = ctx->saved_data["bias"].toBool();
    const at::Tensor grad_bias = bias && ctx->needs_input_grad(2) ? column_sum(grad) : at::Tensor();
    return {grad_x, grad_weight, grad_bias};
  }
};

}  // namespace

at::Tensor linear(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias) {
  TORCH_CHECK(x.defined() && x.dim() == 2 && at::isFloatingType(x.scalar_type()),
              "linear: x must be a floating (N, I) tensor, got ", describe(x));
  TORCH_CHECK(weight.defined() && weight.dim() == 2 && weight.size(1) == x.size(1) &&
                  weight.scalar_type() == x.scalar_type() && weight.device() == x.device(),
              "linear: weight must be a ", x.scalar_type(), " (O, ", x.size(1), ") tensor on ", x.device(), ", got ",
              describe(weight));
  TORCH_CHECK(!bias.defined() || (bias.dim() == 1 && bias.size(0) == weight.size(0) &&
                                  bias.scalar_type() == x.scalar_type() && bias.device() == x.device()),
              "linear: bias must be a ", x.scalar_type(), " (", weight.size(0), ") tensor on ", x.device(), ", got ",
              describe(bias));
  return LinearFunction::apply(x, weight, bias.defined() ? bias : at::empty({0}, x.options()));
}

at::Tensor column_sum(const at::Tensor& rows) {
  TORCH_CHECK(rows.defined() && rows.dim() == 2 && at::isFloatingType(rows.scalar_type()),
              "column_sum: rows must be a floating (R, C) tensor, got ", describe(rows));
  const bool fused = rows.is_cuda() && is_float_or_double(rows);
  if (!fused) return rows.sum(0);
  TORCH_CHECK(cuda::available(), "column_sum: this build has no CUDA backend");
  return cuda::column_sum(rows.contiguous());
}

}  // namespace sfgs::linear
