// The fused GroupNorm + ReLU op: validation at its boundary, the backend by device, and its one autograd node.
#include "group_norm/group_norm.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "common/tensor_description.h"
#include "group_norm/backend.h"
#include "linear/linear.h"

namespace sfgs::group_norm {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// What the backward needs of the forward, typed: the saved tensors in a fixed order.
struct SavedForward {
  at::Tensor pre, bias, gamma, beta, mean, rstd;  // bias empty when the layer has none

  variable_list list() const { return {pre, bias, gamma, beta, mean, rstd}; }
  static SavedForward from(const variable_list& v) { return {v[0], v[1], v[2], v[3], v[4], v[5]}; }
};

template <typename T> const T* data_or_null(const at::Tensor& t) { return t.numel() > 0 ? t.data_ptr<T>() : nullptr; }

template <typename T> void forward_as(const SavedForward& s, const at::Tensor& out, int64_t groups, double epsilon) {
  const GroupNormArrays<T> a{s.pre.data_ptr<T>(),
                             data_or_null<T>(s.bias),
                             s.gamma.data_ptr<T>(),
                             s.beta.data_ptr<T>(),
                             out.data_ptr<T>(),
                             s.mean.data_ptr<T>(),
                             s.rstd.data_ptr<T>(),
                             s.pre.size(0),
                             int(s.pre.size(1)),
                             int(groups),
                             T(epsilon)};
  if (out.is_cuda())
    cuda::forward(a, out.device());
  else
    cpu::forward(a);
}

template <typename T>
void backward_as(const SavedForward& s, const at::Tensor& grad_out, const at::Tensor& grad_pre,
                 const at::Tensor& partials) {
  const GroupNormGradientArrays<T> a{s.pre.data_ptr<T>(),    data_or_null<T>(s.bias), s.gamma.data_ptr<T>(),
                                     s.beta.data_ptr<T>(),   s.mean.data_ptr<T>(),    s.rstd.data_ptr<T>(),
                                     grad_out.data_ptr<T>(), grad_pre.data_ptr<T>(),  partials.data_ptr<T>(),
                                     s.pre.size(0),          int(s.pre.size(1)),      int(s.mean.size(1)),
                                     partials.size(0)};
  if (grad_pre.is_cuda())
    cuda::backward(a, grad_pre.device());
  else
    cpu::backward(a);
}

// The forward of a saved context whose mean and rstd are allocated: out, with the moments filled in.
at::Tensor run_forward(const SavedForward& s, int64_t groups, double epsilon) {
  at::Tensor out = at::empty_like(s.pre);
  if (s.pre.scalar_type() == at::kDouble)
    forward_as<double>(s, out, groups, epsilon);
  else
    forward_as<float>(s, out, groups, epsilon);
  return out;
}

SavedForward new_context(const at::Tensor& pre, const at::Tensor& bias_or_empty, const at::Tensor& gamma,
                         const at::Tensor& beta, int64_t groups) {
  const int64_t n = pre.size(0);
  return {
      pre, bias_or_empty, gamma, beta, at::empty({n, groups}, pre.options()), at::empty({n, groups}, pre.options())};
}

struct ActivationGradients {
  at::Tensor pre, bias, gamma, beta;  // bias undefined when the layer has none
};

ActivationGradients run_backward(const SavedForward& s, const at::Tensor& grad) {
  const int64_t n = s.pre.size(0), c = s.pre.size(1);
  const at::Tensor grad_out = grad.defined() ? grad.contiguous() : at::zeros_like(s.pre);
  const at::Tensor grad_pre = at::empty_like(s.pre);
  const int64_t partial_rows = s.pre.is_cuda() ? cuda::partial_rows(n, s.pre.device()) : cpu::partial_rows(n);
  const at::Tensor partials = at::empty({partial_rows, 3 * c}, s.pre.options());
  if (s.pre.scalar_type() == at::kDouble)
    backward_as<double>(s, grad_out, grad_pre, partials);
  else
    backward_as<float>(s, grad_out, grad_pre, partials);
  const at::Tensor columns = linear::column_sum(partials).view({3, c});
  return {grad_pre, s.bias.numel() > 0 ? columns[2] : at::Tensor(), columns[0], columns[1]};
}

// One node: pre, bias (an empty tensor for none: LibTorch 1.13's custom functions take no undefined inputs), gamma
// and beta in; the activation out.
class GroupNormReluFunction : public torch::autograd::Function<GroupNormReluFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& pre, const at::Tensor& bias_or_empty,
                            const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon) {
    const SavedForward s = new_context(pre, bias_or_empty, gamma, beta, groups);
    const at::Tensor out = run_forward(s, groups, epsilon);
    ctx->save_for_backward(s.list());
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const ActivationGradients g = run_backward(SavedForward::from(ctx->get_saved_variables()), grads[0]);
    return {g.pre, g.bias, g.gamma, g.beta, at::Tensor(), at::Tensor()};
  }
};

// The layer with its linear map: x and weight in (the product pre = x weight^T is recomputed in the backward, not
// kept), then as GroupNormReluFunction.
class LinearGroupNormReluFunction : public torch::autograd::Function<LinearGroupNormReluFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& weight,
                            const at::Tensor& bias_or_empty, const at::Tensor& gamma, const at::Tensor& beta,
                            int64_t groups, double epsilon) {
    SavedForward s = new_context(at::mm(x, weight.t()), bias_or_empty, gamma, beta, groups);
    const at::Tensor out = run_forward(s, groups, epsilon);
    s.pre = at::Tensor();
    ctx->save_for_backward({x, weight, s.bias, s.gamma, s.beta, s.mean, s.rstd});
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const at::Tensor& x = saved[0];
    const at::Tensor& weight = saved[1];
    const SavedForward s{at::mm(x, weight.t()), saved[2], saved[3], saved[4], saved[5], saved[6]};
    const ActivationGradients g = run_backward(s, grads[0]);
    return {g.pre.mm(weight), g.pre.t().mm(x), g.bias, g.gamma, g.beta, at::Tensor(), at::Tensor()};
  }
};

// A layer of `channels` channels on `like`'s dtype and device: its bias (optional), gamma, beta and GroupNorm.
void check_layer(const at::Tensor& like, int64_t channels, const at::Tensor& bias, const at::Tensor& gamma,
                 const at::Tensor& beta, int64_t groups, double epsilon) {
  TORCH_CHECK(groups > 0 && channels > 0 && channels % groups == 0, "group_norm_relu: the ", channels,
              " channels must split into the ", groups, " groups");
  TORCH_CHECK(epsilon > 0, "group_norm_relu: epsilon must be positive, got ", epsilon);
  TORCH_CHECK(like.is_cpu() || like.is_cuda(), "group_norm_relu: tensors must be on the CPU or a CUDA device, got ",
              describe(like));
  const auto check_vector = [&](const at::Tensor& t, const char* name) {
    TORCH_CHECK(t.defined() && t.dim() == 1 && t.size(0) == channels && t.scalar_type() == like.scalar_type() &&
                    t.device() == like.device(),
                "group_norm_relu: ", name, " must be a ", like.scalar_type(), " (", channels, ") tensor on ",
                like.device(), ", got ", describe(t));
  };
  if (bias.defined()) check_vector(bias, "bias");
  check_vector(gamma, "gamma");
  check_vector(beta, "beta");
}

void check_inputs(const at::Tensor& pre, const at::Tensor& bias, const at::Tensor& gamma, const at::Tensor& beta,
                  int64_t groups, double epsilon) {
  TORCH_CHECK(pre.defined() && pre.dim() == 2 && is_float_or_double(pre),
              "group_norm_relu: pre must be a float32 or float64 (N, C) tensor, got ", describe(pre));
  check_layer(pre, pre.size(1), bias, gamma, beta, groups, epsilon);
}

bool fuses_layer(at::Device device, int64_t channels, int64_t groups) {
  if (device.is_cpu()) return true;
  return device.is_cuda() && cuda::available() && cuda::supports(channels, groups);
}

}  // namespace

at::Tensor group_norm_relu_reference(const at::Tensor& pre, const at::Tensor& bias, const at::Tensor& gamma,
                                     const at::Tensor& beta, int64_t groups, double epsilon) {
  check_inputs(pre, bias, gamma, beta, groups, epsilon);
  const int64_t n = pre.size(0), c = pre.size(1);
  const at::Tensor h = bias.defined() ? pre + bias : pre;
  const at::Tensor grouped = h.reshape({n, groups, c / groups});
  const auto [variance, mean] = at::var_mean(grouped, {2}, /*unbiased=*/false, /*keepdim=*/true);
  const at::Tensor normalised = ((grouped - mean) * at::rsqrt(variance + epsilon)).view({n, c});
  return at::relu(at::addcmul(beta, normalised, gamma));
}

bool fuses(const at::Tensor& pre, int64_t groups) { return fuses_layer(pre.device(), pre.size(1), groups); }

at::Tensor group_norm_relu(const at::Tensor& pre, const at::Tensor& bias, const at::Tensor& gamma,
                           const at::Tensor& beta, int64_t groups, double epsilon) {
  check_inputs(pre, bias, gamma, beta, groups, epsilon);
  if (!fuses(pre, groups)) return group_norm_relu_reference(pre, bias, gamma, beta, groups, epsilon);
  const at::Tensor bias_or_empty = bias.defined() ? bias.contiguous() : at::empty({0}, pre.options());
  return GroupNormReluFunction::apply(pre.contiguous(), bias_or_empty, gamma.contiguous(), beta.contiguous(), groups,
                                      epsilon);
}

at::Tensor linear_group_norm_relu(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                                  const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon) {
  TORCH_CHECK(x.defined() && x.dim() == 2 && is_float_or_double(x),
              "linear_group_norm_relu: x must be a float32 or float64 (N, I) tensor, got ", describe(x));
  TORCH_CHECK(weight.defined() && weight.dim() == 2 && weight.size(1) == x.size(1) &&
                  weight.scalar_type() == x.scalar_type() && weight.device() == x.device(),
              "linear_group_norm_relu: weight must be a ", x.scalar_type(), " (C, ", x.size(1), ") tensor on ",
              x.device(), ", got ", describe(weight));
  check_layer(x, weight.size(0), bias, gamma, beta, groups, epsilon);
  if (!fuses_layer(x.device(), weight.size(0), groups))
    return group_norm_relu_reference(at::mm(x, weight.t()), bias, gamma, beta, groups, epsilon);
  const at::Tensor bias_or_empty = bias.defined() ? bias.contiguous() : at::empty({0}, x.options());
  return LinearGroupNormReluFunction::apply(x.contiguous(), weight.contiguous(), bias_or_empty, gamma.contiguous(),
                                            beta.contiguous(), groups, epsilon);
}

}  // namespace sfgs::group_norm
