// The fused GroupNorm + ReLU ops: validation at their boundary and their dispatcher registration
// (ops/registration.h): CPU and CUDA kernels that route to the backend by device, Meta kernels, one autograd node each.
#include "ops/group_norm/group_norm.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/registration.h"
#include "ops/group_norm/backend.h"
#include "ops/linear/linear.h"

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
#if defined(SFGS_WITH_CUDA)
  if (out.is_cuda()) return cuda::forward(a, out.device());
#endif
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
#if defined(SFGS_WITH_CUDA)
  if (grad_pre.is_cuda()) return cuda::backward(a, grad_pre.device());
#endif
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
#if defined(SFGS_WITH_CUDA)
  const int64_t partial_rows = s.pre.is_cuda() ? cuda::partial_rows(n, s.pre.device()) : cpu::partial_rows(n);
#else
  const int64_t partial_rows = cpu::partial_rows(n);
#endif
  const at::Tensor partials = at::empty({partial_rows, 3 * c}, s.pre.options());
  if (s.pre.scalar_type() == at::kDouble)
    backward_as<double>(s, grad_out, grad_pre, partials);
  else
    backward_as<float>(s, grad_out, grad_pre, partials);
  const at::Tensor columns = linear::column_sum(partials).view({3, c});
  return {grad_pre, s.bias.numel() > 0 ? columns[2] : at::Tensor(), columns[0], columns[1]};
}

// A layer of `channels` channels on `like`'s dtype and device: its bias (optional), gamma, beta and GroupNorm.
void check_layer(const at::Tensor& like, int64_t channels, const at::Tensor& bias, const at::Tensor& gamma,
                 const at::Tensor& beta, int64_t groups, double epsilon) {
  TORCH_CHECK(groups > 0 && channels > 0 && channels % groups == 0, "group_norm_relu: the ", channels,
              " channels must split into the ", groups, " groups");
  TORCH_CHECK(epsilon > 0, "group_norm_relu: epsilon must be positive, got ", epsilon);
  TORCH_CHECK(like.is_cpu() || like.is_cuda() || like.is_meta(),
              "group_norm_relu: tensors must be on the CPU or a CUDA device, got ", describe(like));
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
#if defined(SFGS_WITH_CUDA)
  return device.is_cuda() && cuda::supports(channels, groups);
#else
  return false;
#endif
}

// ---- the dispatcher ops (ops/registration.h) ----

using ops::optional_tensor;
using ops::OptionalTensor;
using ForwardOutputs = std::tuple<at::Tensor, at::Tensor, at::Tensor>;               // out, mean, rstd
using BackwardOutputs = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor>;  // pre, bias, gamma, beta

// The moments are outputs so that the autograd node can keep them; the bias's gradient is empty without a bias.
constexpr const char* kForwardSchema =
    "group_norm_relu(Tensor pre, Tensor? bias, Tensor gamma, Tensor beta, int groups, float epsilon) "
    "-> (Tensor out, Tensor mean, Tensor rstd)";
constexpr const char* kLinearSchema =
    "linear_group_norm_relu(Tensor x, Tensor weight, Tensor? bias, Tensor gamma, Tensor beta, int groups, "
    "float epsilon) -> (Tensor out, Tensor mean, Tensor rstd)";
constexpr const char* kBackwardSchema =
    "group_norm_relu_backward(Tensor grad_out, Tensor pre, Tensor? bias, Tensor gamma, Tensor beta, Tensor mean, "
    "Tensor rstd) -> (Tensor grad_pre, Tensor grad_bias, Tensor grad_gamma, Tensor grad_beta)";
using ForwardSignature = ForwardOutputs(const at::Tensor&, const OptionalTensor&, const at::Tensor&, const at::Tensor&,
                                        int64_t, double);
using LinearSignature = ForwardOutputs(const at::Tensor&, const at::Tensor&, const OptionalTensor&, const at::Tensor&,
                                       const at::Tensor&, int64_t, double);
using BackwardSignature = BackwardOutputs(const at::Tensor&, const at::Tensor&, const OptionalTensor&,
                                          const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&);

const c10::TypedOperatorHandle<ForwardSignature>& forward_op() {
  static const auto handle = ops::find_op<ForwardSignature>("sfgs::group_norm_relu");
  return handle;
}
const c10::TypedOperatorHandle<LinearSignature>& linear_op() {
  static const auto handle = ops::find_op<LinearSignature>("sfgs::linear_group_norm_relu");
  return handle;
}
const c10::TypedOperatorHandle<BackwardSignature>& backward_op() {
  static const auto handle = ops::find_op<BackwardSignature>("sfgs::group_norm_relu_backward");
  return handle;
}

at::Tensor bias_or_empty(const OptionalTensor& bias, const at::Tensor& like) {
  return bias.has_value() ? bias->contiguous() : at::empty({0}, like.options());
}

// A backend kernel's own checks: what group_norm_relu checks, and on CUDA the shapes the kernel takes.
void check_backend_inputs(const at::Tensor& pre, const OptionalTensor& bias, const at::Tensor& gamma,
                          const at::Tensor& beta, int64_t groups, double epsilon) {
  check_inputs(pre, bias.value_or(at::Tensor()), gamma, beta, groups, epsilon);
  TORCH_CHECK(pre.is_meta() || fuses_layer(pre.device(), pre.size(1), groups), "sfgs::group_norm_relu: the ",
              pre.device(), " kernel does not take ", pre.size(1), " channels in ", groups,
              " groups (group_norm::fuses says which shapes run fused; others take the reference)");
}

ForwardOutputs forward_kernel(const at::Tensor& pre, const OptionalTensor& bias, const at::Tensor& gamma,
                              const at::Tensor& beta, int64_t groups, double epsilon) {
  check_backend_inputs(pre, bias, gamma, beta, groups, epsilon);
  const SavedForward s =
      new_context(pre.contiguous(), bias_or_empty(bias, pre), gamma.contiguous(), beta.contiguous(), groups);
  const at::Tensor out = run_forward(s, groups, epsilon);
  return {out, s.mean, s.rstd};
}

ForwardOutputs forward_meta(const at::Tensor& pre, const OptionalTensor& bias, const at::Tensor& gamma,
                            const at::Tensor& beta, int64_t groups, double epsilon) {
  check_backend_inputs(pre, bias, gamma, beta, groups, epsilon);
  const SavedForward s = new_context(pre, bias_or_empty(bias, pre), gamma, beta, groups);
  return {at::empty_like(pre), s.mean, s.rstd};
}

void check_linear_inputs(const at::Tensor& x, const at::Tensor& weight) {
  TORCH_CHECK(x.defined() && x.dim() == 2 && is_float_or_double(x),
              "linear_group_norm_relu: x must be a float32 or float64 (N, I) tensor, got ", describe(x));
  TORCH_CHECK(weight.defined() && weight.dim() == 2 && weight.size(1) == x.size(1) &&
                  weight.scalar_type() == x.scalar_type() && weight.device() == x.device(),
              "linear_group_norm_relu: weight must be a ", x.scalar_type(), " (C, ", x.size(1), ") tensor on ",
              x.device(), ", got ", describe(weight));
}

ForwardOutputs linear_kernel(const at::Tensor& x, const at::Tensor& weight, const OptionalTensor& bias,
                             const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon) {
  check_linear_inputs(x, weight);
  return forward_kernel(at::mm(x, weight.t()), bias, gamma, beta, groups, epsilon);
}

ForwardOutputs linear_meta(const at::Tensor& x, const at::Tensor& weight, const OptionalTensor& bias,
                           const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon) {
  check_linear_inputs(x, weight);
  return forward_meta(at::empty({x.size(0), weight.size(0)}, x.options()), bias, gamma, beta, groups, epsilon);
}

// The backward reads the moments, not epsilon: any positive value passes the forward's checks.
constexpr double kAnyEpsilon = 1;

void check_backward_inputs(const at::Tensor& grad_out, const at::Tensor& pre, const OptionalTensor& bias,
                           const at::Tensor& gamma, const at::Tensor& beta, const at::Tensor& mean,
                           const at::Tensor& rstd) {
  TORCH_CHECK(mean.dim() == 2 && mean.size(0) == pre.size(0) && mean.size(1) > 0,
              "sfgs::group_norm_relu_backward: mean must be (N, groups) with N = ", pre.size(0), ", got ",
              describe(mean));
  check_backend_inputs(pre, bias, gamma, beta, mean.size(1), kAnyEpsilon);
  const auto check_like = [&](const at::Tensor& t, const at::Tensor& like, const char* name) {
    TORCH_CHECK(t.sizes() == like.sizes() && t.scalar_type() == pre.scalar_type() && t.device() == pre.device(),
                "sfgs::group_norm_relu_backward: ", name, " must be a ", pre.scalar_type(), " ", like.sizes(),
                " tensor on ", pre.device(), ", got ", describe(t));
  };
  check_like(grad_out, pre, "grad_out");
  check_like(mean, mean, "mean");
  check_like(rstd, mean, "rstd");
}

BackwardOutputs backward_kernel(const at::Tensor& grad_out, const at::Tensor& pre, const OptionalTensor& bias,
                                const at::Tensor& gamma, const at::Tensor& beta, const at::Tensor& mean,
                                const at::Tensor& rstd) {
  check_backward_inputs(grad_out, pre, bias, gamma, beta, mean, rstd);
  const SavedForward s{pre.contiguous(),  bias_or_empty(bias, pre), gamma.contiguous(),
                       beta.contiguous(), mean.contiguous(),        rstd.contiguous()};
  const ActivationGradients g = run_backward(s, grad_out);
  return {g.pre, g.bias.defined() ? g.bias : at::empty({0}, pre.options()), g.gamma, g.beta};
}

BackwardOutputs backward_meta(const at::Tensor& grad_out, const at::Tensor& pre, const OptionalTensor& bias,
                              const at::Tensor& gamma, const at::Tensor& beta, const at::Tensor& mean,
                              const at::Tensor& rstd) {
  check_backward_inputs(grad_out, pre, bias, gamma, beta, mean, rstd);
  return {at::empty_like(pre), at::empty({bias.has_value() ? pre.size(1) : 0}, pre.options()), at::empty_like(gamma),
          at::empty_like(beta)};
}

// The op's one autograd node: pre, bias, gamma and beta in; the activation out (the moments are not differentiable).
class GroupNormReluFunction : public torch::autograd::Function<GroupNormReluFunction> {
 public:
  static variable_list forward(AutogradContext* ctx, const at::Tensor& pre, const OptionalTensor& bias,
                               const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon) {
    ForwardOutputs out;
    {
      const at::AutoDispatchBelowADInplaceOrView below_autograd;
      out = forward_op().call(pre, bias, gamma, beta, groups, epsilon);
    }
    const auto& [activation, mean, rstd] = out;
    ctx->save_for_backward({pre, bias_or_empty(bias, pre), gamma, beta, mean, rstd});
    ctx->mark_non_differentiable({mean, rstd});
    ctx->set_materialize_grads(false);  // the moments never get a gradient: no zero-filled tensors for them
    return {activation, mean, rstd};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    if (!grads[0].defined()) return variable_list(6);
    const variable_list v = ctx->get_saved_variables();
    const auto [pre, bias, gamma, beta] = backward_op().call(
        grads[0], v[0], v[1].numel() > 0 ? optional_tensor(v[1]) : c10::nullopt, v[2], v[3], v[4], v[5]);
    return {pre, bias.numel() > 0 ? bias : at::Tensor(), gamma, beta, at::Tensor(), at::Tensor()};
  }
};

// The layer with its linear map: x and weight in; the product pre = x weight^T is recomputed in the backward, not
// kept.
class LinearGroupNormReluFunction : public torch::autograd::Function<LinearGroupNormReluFunction> {
 public:
  static variable_list forward(AutogradContext* ctx, const at::Tensor& x, const at::Tensor& weight,
                               const OptionalTensor& bias, const at::Tensor& gamma, const at::Tensor& beta,
                               int64_t groups, double epsilon) {
    ForwardOutputs out;
    {
      const at::AutoDispatchBelowADInplaceOrView below_autograd;
      out = linear_op().call(x, weight, bias, gamma, beta, groups, epsilon);
    }
    const auto& [activation, mean, rstd] = out;
    ctx->save_for_backward({x, weight, bias_or_empty(bias, x), gamma, beta, mean, rstd});
    ctx->mark_non_differentiable({mean, rstd});
    ctx->set_materialize_grads(false);  // the moments never get a gradient: no zero-filled tensors for them
    return {activation, mean, rstd};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    if (!grads[0].defined()) return variable_list(7);
    const variable_list v = ctx->get_saved_variables();
    const at::Tensor& x = v[0];
    const at::Tensor& weight = v[1];
    const auto [pre, bias, gamma, beta] =
        backward_op().call(grads[0], at::mm(x, weight.t()), v[2].numel() > 0 ? optional_tensor(v[2]) : c10::nullopt,
                           v[3], v[4], v[5], v[6]);
    return {pre.mm(weight), pre.t().mm(x), bias.numel() > 0 ? bias : at::Tensor(), gamma, beta,
            at::Tensor(),   at::Tensor()};
  }
};

ForwardOutputs forward_autograd(const at::Tensor& pre, const OptionalTensor& bias, const at::Tensor& gamma,
                                const at::Tensor& beta, int64_t groups, double epsilon) {
  const variable_list out = GroupNormReluFunction::apply(pre, bias, gamma, beta, groups, epsilon);
  return {out[0], out[1], out[2]};
}

ForwardOutputs linear_autograd(const at::Tensor& x, const at::Tensor& weight, const OptionalTensor& bias,
                               const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon) {
  const variable_list out = LinearGroupNormReluFunction::apply(x, weight, bias, gamma, beta, groups, epsilon);
  return {out[0], out[1], out[2]};
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
  return std::get<0>(forward_op().call(pre, optional_tensor(bias), gamma, beta, groups, epsilon));
}

at::Tensor linear_group_norm_relu(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                                  const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon) {
  check_linear_inputs(x, weight);
  check_layer(x, weight.size(0), bias, gamma, beta, groups, epsilon);
  if (!fuses_layer(x.device(), weight.size(0), groups))
    return group_norm_relu_reference(at::mm(x, weight.t()), bias, gamma, beta, groups, epsilon);
  return std::get<0>(linear_op().call(x, weight, optional_tensor(bias), gamma, beta, groups, epsilon));
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kForwardSchema);
  m.def(kLinearSchema);
  m.def(kBackwardSchema);
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("group_norm_relu", TORCH_FN(forward_kernel));
  m.impl("linear_group_norm_relu", TORCH_FN(linear_kernel));
  m.impl("group_norm_relu_backward", TORCH_FN(backward_kernel));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("group_norm_relu", TORCH_FN(forward_kernel));
  m.impl("linear_group_norm_relu", TORCH_FN(linear_kernel));
  m.impl("group_norm_relu_backward", TORCH_FN(backward_kernel));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("group_norm_relu", TORCH_FN(forward_meta));
  m.impl("linear_group_norm_relu", TORCH_FN(linear_meta));
  m.impl("group_norm_relu_backward", TORCH_FN(backward_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) {
  m.impl("group_norm_relu", TORCH_FN(forward_autograd));
  m.impl("linear_group_norm_relu", TORCH_FN(linear_autograd));
}

}  // namespace sfgs::group_norm
