// The fused SSIM: validation at its boundary and its dispatcher registration (ops/registration.h): CPU and CUDA
// kernels that route to the backend by device, Meta kernels, one autograd node.
#include "ops/ssim/ssim.h"

#include <limits>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/registration.h"
#include "ops/ssim/backend.h"
#include "ops/ssim/constants.h"

namespace sfgs::ssim {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// The forward's result: the mean SSIM and, when a gradient is wanted, the derivative maps the backward filters.
struct ForwardResult {
  at::Tensor mean;
  at::Tensor derivative_maps;  // (3, C, H, W) or undefined
};

// What the backward needs of the forward, typed: the saved tensors in a fixed order.
struct SavedForward {
  at::Tensor prediction, target, derivative_maps;

  variable_list list() const { return {prediction, target, derivative_maps}; }
  static SavedForward from(const variable_list& v) { return {v[0], v[1], v[2]}; }
};

template <typename T> void fill_window(T (&taps)[kSsimWindowSize]) {
  const auto window = gaussian_window();
  for (int k = 0; k < kSsimWindowSize; ++k) taps[k] = T(window[k]);
}

template <typename T>
void forward_as(const at::Tensor& prediction, const at::Tensor& target, const at::Tensor& partial_sums,
                const at::Tensor& derivative_maps) {
  SsimArrays<T> a{};
  a.prediction = prediction.data_ptr<T>();
  a.target = target.data_ptr<T>();
  a.partial_sums = partial_sums.data_ptr<T>();
  a.derivative_maps = derivative_maps.defined() ? derivative_maps.data_ptr<T>() : nullptr;
  a.height = int(prediction.size(0));
  a.width = int(prediction.size(1));
  a.channels = int(prediction.size(2));
  fill_window(a.taps);
  a.c1 = T(ssim_c1());
  a.c2 = T(ssim_c2());
#if defined(SFGS_WITH_CUDA)
  if (prediction.is_cuda()) return cuda::forward(a, prediction.device());
#endif
  cpu::forward(a);
}

template <typename T>
void backward_as(const SavedForward& s, const at::Tensor& grad_mean, const at::Tensor& grad_prediction) {
  SsimGradientArrays<T> a{};
  a.prediction = s.prediction.data_ptr<T>();
  a.target = s.target.data_ptr<T>();
  a.derivative_maps = s.derivative_maps.data_ptr<T>();
  a.grad_mean = grad_mean.data_ptr<T>();
  a.grad_prediction = grad_prediction.data_ptr<T>();
  a.height = int(s.prediction.size(0));
  a.width = int(s.prediction.size(1));
  a.channels = int(s.prediction.size(2));
  fill_window(a.taps);
  a.inverse_count = T(1.0 / double(s.prediction.numel()));
#if defined(SFGS_WITH_CUDA)
  if (grad_prediction.is_cuda()) return cuda::backward(a, grad_prediction.device());
#endif
  cpu::backward(a);
}

// The mean SSIM of contiguous, validated images; the partial sums are added up on the device (no host read).
ForwardResult run_forward(const at::Tensor& prediction, const at::Tensor& target, bool with_derivatives) {
  const int64_t h = prediction.size(0), w = prediction.size(1), c = prediction.size(2);
#if defined(SFGS_WITH_CUDA)
  const int64_t partial_count =
      prediction.is_cuda() ? cuda::partial_sums(h, w, c, prediction.scalar_type()) : cpu::partial_sums(h, w, c);
#else
  const int64_t partial_count = cpu::partial_sums(h, w, c);
#endif
  const at::Tensor partial_sums = at::empty({partial_count}, prediction.options());
  ForwardResult r;
  if (with_derivatives) r.derivative_maps = at::empty({kDerivativeMaps, c, h, w}, prediction.options());
  if (prediction.scalar_type() == at::kDouble)
    forward_as<double>(prediction, target, partial_sums, r.derivative_maps);
  else
    forward_as<float>(prediction, target, partial_sums, r.derivative_maps);
  r.mean = partial_sums.sum() / double(prediction.numel());
  return r;
}

// `on_meta`: the Meta kernels' check, which also takes meta tensors.
void check_inputs(const at::Tensor& prediction, const at::Tensor& target, bool on_meta = false) {
  for (const auto* image : {&prediction, &target}) {
    const char* name = image == &prediction ? "prediction" : "target";
    TORCH_CHECK(image->defined() && image->dim() == 3 && is_float_or_double(*image), "fused_ssim: ", name,
                " must be a float32 or float64 image (H, W, C), got ", describe(*image));
    // Meta kernels leave out what needs the element count: under tracing the sizes may be symbolic.
    if (!on_meta) TORCH_CHECK(image->numel() > 0, "fused_ssim: ", name, " must not be empty, got ", describe(*image));
    TORCH_CHECK(image->is_cpu() || image->is_cuda() || (on_meta && image->is_meta()), "fused_ssim: ", name,
                " must be on the CPU or a CUDA device, got ", describe(*image));
  }
  TORCH_CHECK(!prediction.is_cuda() || ops::kBuiltWithCuda,
              "fused_ssim: this build has no CUDA backend (rebuild against a CUDA LibTorch), got ",
              describe(prediction));
  TORCH_CHECK(prediction.sizes() == target.sizes(), "fused_ssim: prediction and target must have the same shape, got ",
              describe(prediction), " and ", describe(target));
  TORCH_CHECK(prediction.scalar_type() == target.scalar_type() && prediction.device() == target.device(),
              "fused_ssim: prediction and target must share dtype and device, got ", describe(prediction), " and ",
              describe(target));
  // The backends index planes of H x W x C values with 32-bit sizes.
  TORCH_CHECK(on_meta || prediction.numel() <= std::numeric_limits<int>::max(),
              "fused_ssim: images of at most 2^31 - 1 values, got ", describe(prediction));
}

// ---- the dispatcher ops (ops/registration.h) ----

// fused_ssim gives the mean alone; fused_ssim_with_derivatives also the derivative maps its backward filters, which
// the autograd node asks for only when the prediction takes a gradient.
constexpr const char* kSchema = "fused_ssim(Tensor prediction, Tensor target) -> Tensor";
constexpr const char* kWithDerivativesSchema =
    "fused_ssim_with_derivatives(Tensor prediction, Tensor target) -> (Tensor mean, Tensor derivative_maps)";
constexpr const char* kBackwardSchema =
    "fused_ssim_backward(Tensor grad_mean, Tensor prediction, Tensor target, Tensor derivative_maps) -> Tensor";
using Signature = at::Tensor(const at::Tensor&, const at::Tensor&);
using WithDerivativesSignature = std::tuple<at::Tensor, at::Tensor>(const at::Tensor&, const at::Tensor&);
using BackwardSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&);

const c10::TypedOperatorHandle<Signature>& mean_op() {
  static const auto handle = ops::find_op<Signature>("sfgs::fused_ssim");
  return handle;
}
const c10::TypedOperatorHandle<WithDerivativesSignature>& with_derivatives_op() {
  static const auto handle = ops::find_op<WithDerivativesSignature>("sfgs::fused_ssim_with_derivatives");
  return handle;
}
const c10::TypedOperatorHandle<BackwardSignature>& backward_op() {
  static const auto handle = ops::find_op<BackwardSignature>("sfgs::fused_ssim_backward");
  return handle;
}

at::Tensor mean_kernel(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  return run_forward(prediction.contiguous(), target.contiguous(), /*with_derivatives=*/false).mean;
}

at::Tensor mean_meta(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target, /*on_meta=*/true);
  return at::empty({}, prediction.options());
}

std::tuple<at::Tensor, at::Tensor> with_derivatives_kernel(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  const ForwardResult r = run_forward(prediction.contiguous(), target.contiguous(), /*with_derivatives=*/true);
  return {r.mean, r.derivative_maps};
}

std::tuple<at::Tensor, at::Tensor> with_derivatives_meta(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target, /*on_meta=*/true);
  const int64_t h = prediction.size(0), w = prediction.size(1), c = prediction.size(2);
  return {at::empty({}, prediction.options()), at::empty({kDerivativeMaps, c, h, w}, prediction.options())};
}

void check_backward_inputs(const at::Tensor& grad_mean, const at::Tensor& prediction, const at::Tensor& target,
                           const at::Tensor& derivative_maps, bool on_meta = false) {
  check_inputs(prediction, target, on_meta);
  TORCH_CHECK((on_meta || grad_mean.numel() == 1) && grad_mean.scalar_type() == prediction.scalar_type() &&
                  grad_mean.device() == prediction.device(),
              "sfgs::fused_ssim_backward: grad_mean must be one ", prediction.scalar_type(), " value on ",
              prediction.device(), ", got ", describe(grad_mean));
  const at::IntArrayRef sizes = derivative_maps.sizes();
  TORCH_CHECK(derivative_maps.dim() == 4 && sizes[0] == kDerivativeMaps && sizes[1] == prediction.size(2) &&
                  sizes[2] == prediction.size(0) && sizes[3] == prediction.size(1) &&
                  derivative_maps.scalar_type() == prediction.scalar_type() &&
                  derivative_maps.device() == prediction.device(),
              "sfgs::fused_ssim_backward: derivative_maps must be (", kDerivativeMaps, ", C, H, W) like the ",
              "prediction's, got ", describe(derivative_maps));
}

at::Tensor backward_kernel(const at::Tensor& grad_mean, const at::Tensor& prediction, const at::Tensor& target,
                           const at::Tensor& derivative_maps) {
  check_backward_inputs(grad_mean, prediction, target, derivative_maps);
  const SavedForward s{prediction.contiguous(), target.contiguous(), derivative_maps.contiguous()};
  at::Tensor grad_prediction = at::empty_like(s.prediction);
  const at::Tensor g = grad_mean.reshape({}).contiguous();
  if (s.prediction.scalar_type() == at::kDouble)
    backward_as<double>(s, g, grad_prediction);
  else
    backward_as<float>(s, g, grad_prediction);
  return grad_prediction;
}

at::Tensor backward_meta(const at::Tensor& grad_mean, const at::Tensor& prediction, const at::Tensor& target,
                         const at::Tensor& derivative_maps) {
  check_backward_inputs(grad_mean, prediction, target, derivative_maps, /*on_meta=*/true);
  return at::empty_like(prediction, at::MemoryFormat::Contiguous);
}

// The op's one autograd node: the prediction (differentiated) and the target (a constant) in; the mean SSIM out.
class FusedSsimFunction : public torch::autograd::Function<FusedSsimFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& prediction, const at::Tensor& target) {
    std::tuple<at::Tensor, at::Tensor> r;
    {
      const at::AutoDispatchBelowADInplaceOrView below_autograd;
      r = with_derivatives_op().call(prediction, target);
    }
    ctx->save_for_backward(SavedForward{prediction, target, std::get<1>(r)}.list());
    return std::get<0>(r);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    if (!grads[0].defined()) return {at::Tensor(), at::Tensor()};
    const SavedForward s = SavedForward::from(ctx->get_saved_variables());
    return {backward_op().call(grads[0], s.prediction, s.target, s.derivative_maps), at::Tensor()};
  }
};

at::Tensor autograd_kernel(const at::Tensor& prediction, const at::Tensor& target) {
  TORCH_CHECK(!target.requires_grad(),
              "fused_ssim: the target must not require a gradient (the op differentiates the prediction only; use "
              "metrics::ssim for both), got ",
              describe(target), " that requires grad");
  if (at::GradMode::is_enabled() && prediction.requires_grad()) return FusedSsimFunction::apply(prediction, target);
  const at::AutoDispatchBelowADInplaceOrView below_autograd;
  return mean_op().call(prediction, target);
}

}  // namespace

at::Tensor fused_ssim(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  return mean_op().call(prediction, target);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kSchema);
  m.def(kWithDerivativesSchema);
  m.def(kBackwardSchema);
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("fused_ssim", TORCH_FN(mean_kernel));
  m.impl("fused_ssim_with_derivatives", TORCH_FN(with_derivatives_kernel));
  m.impl("fused_ssim_backward", TORCH_FN(backward_kernel));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("fused_ssim", TORCH_FN(mean_kernel));
  m.impl("fused_ssim_with_derivatives", TORCH_FN(with_derivatives_kernel));
  m.impl("fused_ssim_backward", TORCH_FN(backward_kernel));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("fused_ssim", TORCH_FN(mean_meta));
  m.impl("fused_ssim_with_derivatives", TORCH_FN(with_derivatives_meta));
  m.impl("fused_ssim_backward", TORCH_FN(backward_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("fused_ssim", TORCH_FN(autograd_kernel)); }

}  // namespace sfgs::ssim
