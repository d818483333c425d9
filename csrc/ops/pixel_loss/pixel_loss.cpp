// The fused pixel-loss op: validation at its boundary and its dispatcher registration (ops/registration.h): CPU and
// CUDA kernels that route to the backend by device, Meta kernels, one autograd node.
#include "ops/pixel_loss/pixel_loss.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "ops/pixel_loss/constants.h"
#include "common/tensor_description.h"
#include "ops/registration.h"
#include "ops/pixel_loss/backend.h"

namespace sfgs::pixel_loss {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

at::Tensor srgb_to_linear(const at::Tensor& c) {
  const at::Tensor clamped = c.clamp(0, 1);
  return at::where(clamped <= 0.04045, clamped / 12.92, at::pow((clamped + 0.055) / 1.055, 2.4));
}

at::Tensor lab_f(const at::Tensor& t) {
  // The cube root's slope is infinite at 0; the linear branch covers t <= kLabLinearBelow, so clamping there is exact.
  return at::where(t > kLabLinearBelow, at::pow(t.clamp_min(kLabLinearBelow), 1.0 / 3.0),
                   (24389.0 / 27.0 * t + 16.0) / 116.0);
}

template <typename T> at::Tensor forward_as(const at::Tensor& prediction, const at::Tensor& target) {
  const int height = int(prediction.size(0)), width = int(prediction.size(1));
#if defined(SFGS_WITH_CUDA)
  const int64_t partials = prediction.is_cuda() ? cuda::partials(height, width) : cpu::partials(height);
#else
  const int64_t partials = cpu::partials(height);
#endif
  const at::Tensor sums = at::empty({partials, kSums}, prediction.options());
  const PixelLossArrays<T> a{
      prediction.data_ptr<T>(), target.data_ptr<T>(), sums.data_ptr<T>(), partials, height, width};
#if defined(SFGS_WITH_CUDA)
  if (prediction.is_cuda()) {
    cuda::forward(a, prediction.device());
    return sums.sum(0);
  }
#endif
  cpu::forward(a);
  return sums.sum(0);
}

template <typename T>
at::Tensor backward_as(const at::Tensor& prediction, const at::Tensor& target, const at::Tensor& weights) {
  const at::Tensor grad = at::empty_like(prediction);
  const at::Tensor w = weights.contiguous();  // stays on the device: no host read in the backward
  const PixelLossGradientArrays<T> a{prediction.data_ptr<T>(), target.data_ptr<T>(),    w.data_ptr<T>(),
                                     grad.data_ptr<T>(),       int(prediction.size(0)), int(prediction.size(1))};
#if defined(SFGS_WITH_CUDA)
  if (prediction.is_cuda()) {
    cuda::backward(a, prediction.device());
    return grad;
  }
#endif
  cpu::backward(a);
  return grad;
}

void check_inputs(const at::Tensor& prediction, const at::Tensor& target) {
  TORCH_CHECK(prediction.defined() && prediction.dim() == 3 && prediction.size(2) == 3 && prediction.size(0) >= 2 &&
                  prediction.size(1) >= 2 && is_float_or_double(prediction),
              "pixel_losses: prediction must be a float32 or float64 (H, W, 3) image with H, W >= 2, got ",
              describe(prediction));
  TORCH_CHECK(target.defined() && target.sizes() == prediction.sizes() &&
                  target.scalar_type() == prediction.scalar_type() && target.device() == prediction.device(),
              "pixel_losses: target must be like the prediction (", describe(prediction), "), got ", describe(target));
  TORCH_CHECK(prediction.is_cpu() || prediction.is_cuda() || prediction.is_meta(),
              "pixel_losses: tensors must be on the CPU or a CUDA device, got ", describe(prediction));
}

// ---- the dispatcher ops (ops/registration.h) ----

constexpr const char* kForwardSchema = "pixel_losses(Tensor prediction, Tensor target) -> Tensor";
constexpr const char* kBackwardSchema =
    "pixel_losses_backward(Tensor grad, Tensor prediction, Tensor target) -> Tensor";
using ForwardSignature = at::Tensor(const at::Tensor&, const at::Tensor&);
using BackwardSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&);

const c10::TypedOperatorHandle<ForwardSignature>& forward_op() {
  static const auto handle = ops::find_op<ForwardSignature>("sfgs::pixel_losses");
  return handle;
}
const c10::TypedOperatorHandle<BackwardSignature>& backward_op() {
  static const auto handle = ops::find_op<BackwardSignature>("sfgs::pixel_losses_backward");
  return handle;
}

at::Tensor forward_kernel(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  const at::Tensor p = prediction.contiguous(), t = target.contiguous();
  return p.scalar_type() == at::kDouble ? forward_as<double>(p, t) : forward_as<float>(p, t);
}

at::Tensor forward_meta(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  return at::empty({kSums}, prediction.options());
}

void check_backward_inputs(const at::Tensor& grad, const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  TORCH_CHECK(grad.dim() == 1 && grad.size(0) == kSums && grad.scalar_type() == prediction.scalar_type() &&
                  grad.device() == prediction.device(),
              "sfgs::pixel_losses_backward: grad must be a ", prediction.scalar_type(), " (", kSums, ") tensor on ",
              prediction.device(), ", got ", describe(grad));
}

at::Tensor backward_kernel(const at::Tensor& grad, const at::Tensor& prediction, const at::Tensor& target) {
  check_backward_inputs(grad, prediction, target);
  const at::Tensor p = prediction.contiguous(), t = target.contiguous();
  return p.scalar_type() == at::kDouble ? backward_as<double>(p, t, grad) : backward_as<float>(p, t, grad);
}

at::Tensor backward_meta(const at::Tensor& grad, const at::Tensor& prediction, const at::Tensor& target) {
  check_backward_inputs(grad, prediction, target);
  return at::empty_like(prediction, at::MemoryFormat::Contiguous);
}

// The op's one autograd node: prediction and target in (the target takes no gradient), the four means out.
class PixelLossFunction : public torch::autograd::Function<PixelLossFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& prediction, const at::Tensor& target) {
    ctx->save_for_backward({prediction, target});
    const at::AutoDispatchBelowADInplaceOrView below_autograd;
    return forward_op().call(prediction, target);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    if (!grads[0].defined()) return {at::Tensor(), at::Tensor()};
    return {backward_op().call(grads[0], saved[0], saved[1]), at::Tensor()};
  }
};

at::Tensor autograd_kernel(const at::Tensor& prediction, const at::Tensor& target) {
  return PixelLossFunction::apply(prediction, target);
}

}  // namespace

at::Tensor rgb_to_lab(const at::Tensor& rgb) {
  TORCH_CHECK(rgb.size(-1) == 3, "rgb_to_lab: the last axis must hold RGB, got ", rgb.sizes());
  const at::Tensor lin = srgb_to_linear(rgb);
  const at::Tensor r = lin.select(-1, 0), g = lin.select(-1, 1), b = lin.select(-1, 2);
  const at::Tensor x = (0.412453 * r + 0.357580 * g + 0.180423 * b) / 0.95047;
  const at::Tensor y = 0.212671 * r + 0.715160 * g + 0.072169 * b;
  const at::Tensor z = (0.019334 * r + 0.119193 * g + 0.950227 * b) / 1.08883;
  const at::Tensor fx = lab_f(x), fy = lab_f(y), fz = lab_f(z);
  return at::stack({(116.0 * fy - 16.0) / 100.0, 500.0 * (fx - fy) / 110.0, 200.0 * (fy - fz) / 110.0}, -1);
}

at::Tensor pixel_losses_reference(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  const auto dx = [](const at::Tensor& t) { return t.slice(1, 1) - t.slice(1, 0, -1); };
  const auto dy = [](const at::Tensor& t) { return t.slice(0, 1) - t.slice(0, 0, -1); };
  return at::stack({(prediction - target).abs().mean(), (rgb_to_lab(prediction) - rgb_to_lab(target)).abs().mean(),
                    (dx(prediction) - dx(target)).abs().mean(), (dy(prediction) - dy(target)).abs().mean()});
}

at::Tensor pixel_losses(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  TORCH_CHECK(!target.requires_grad(), "pixel_losses: the target is data and takes no gradient; detach it first");
  TORCH_CHECK(!prediction.is_cuda() || ops::kBuiltWithCuda,
              "pixel_losses: got CUDA tensors but this build of sfgs has no CUDA backend");
  return forward_op().call(prediction, target);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kForwardSchema);
  m.def(kBackwardSchema);
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("pixel_losses", TORCH_FN(forward_kernel));
  m.impl("pixel_losses_backward", TORCH_FN(backward_kernel));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("pixel_losses", TORCH_FN(forward_kernel));
  m.impl("pixel_losses_backward", TORCH_FN(backward_kernel));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("pixel_losses", TORCH_FN(forward_meta));
  m.impl("pixel_losses_backward", TORCH_FN(backward_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("pixel_losses", TORCH_FN(autograd_kernel)); }

}  // namespace sfgs::pixel_loss
