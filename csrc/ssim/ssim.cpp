// The fused SSIM: validation at its boundary, the backend by device, and its one autograd node.
#include "ssim/ssim.h"

#include <limits>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "common/tensor_description.h"
#include "ssim/backend.h"

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
  if (prediction.is_cuda())
    cuda::forward(a, prediction.device());
  else
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
  if (grad_prediction.is_cuda())
    cuda::backward(a, grad_prediction.device());
  else
    cpu::backward(a);
}

// The mean SSIM of contiguous, validated images; the partial sums are added up on the device (no host read).
ForwardResult run_forward(const at::Tensor& prediction, const at::Tensor& target, bool with_derivatives) {
  const int64_t h = prediction.size(0), w = prediction.size(1), c = prediction.size(2);
  const int64_t partial_count =
      prediction.is_cuda() ? cuda::partial_sums(h, w, c, prediction.scalar_type()) : cpu::partial_sums(h, w, c);
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

// One node: the prediction (differentiated) and the target (a constant) in; the mean SSIM out.
class FusedSsimFunction : public torch::autograd::Function<FusedSsimFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& prediction, const at::Tensor& target) {
    ForwardResult r = run_forward(prediction, target, /*with_derivatives=*/true);
    ctx->save_for_backward(SavedForward{prediction, target, r.derivative_maps}.list());
    return r.mean;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    if (!grads[0].defined()) return {at::Tensor(), at::Tensor()};
    const SavedForward s = SavedForward::from(ctx->get_saved_variables());
    const at::Tensor grad_mean = grads[0].contiguous();
    at::Tensor grad_prediction = at::empty_like(s.prediction);
    if (s.prediction.scalar_type() == at::kDouble)
      backward_as<double>(s, grad_mean, grad_prediction);
    else
      backward_as<float>(s, grad_mean, grad_prediction);
    return {grad_prediction, at::Tensor()};
  }
};

void check_inputs(const at::Tensor& prediction, const at::Tensor& target) {
  for (const auto* image : {&prediction, &target}) {
    const char* name = image == &prediction ? "prediction" : "target";
    TORCH_CHECK(image->defined() && image->dim() == 3 && is_float_or_double(*image), "fused_ssim: ", name,
                " must be a float32 or float64 image (H, W, C), got ", describe(*image));
    TORCH_CHECK(image->numel() > 0, "fused_ssim: ", name, " must not be empty, got ", describe(*image));
    TORCH_CHECK(image->is_cpu() || image->is_cuda(), "fused_ssim: ", name, " must be on the CPU or a CUDA device, got ",
                describe(*image));
  }
  TORCH_CHECK(!prediction.is_cuda() || cuda::available(),
              "fused_ssim: this build has no CUDA backend (rebuild against a CUDA LibTorch), got ",
              describe(prediction));
  TORCH_CHECK(prediction.sizes() == target.sizes(), "fused_ssim: prediction and target must have the same shape, got ",
              describe(prediction), " and ", describe(target));
  TORCH_CHECK(prediction.scalar_type() == target.scalar_type() && prediction.device() == target.device(),
              "fused_ssim: prediction and target must share dtype and device, got ", describe(prediction), " and ",
              describe(target));
  // The backends index planes of H x W x C values with 32-bit sizes.
  TORCH_CHECK(prediction.numel() <= std::numeric_limits<int>::max(),
              "fused_ssim: images of at most 2^31 - 1 values, got ", describe(prediction));
  TORCH_CHECK(!target.requires_grad(),
              "fused_ssim: the target must not require a gradient (the op differentiates the prediction only; use "
              "metrics::ssim for both), got ",
              describe(target), " that requires grad");
}

}  // namespace

at::Tensor fused_ssim(const at::Tensor& prediction, const at::Tensor& target) {
  check_inputs(prediction, target);
  const at::Tensor p = prediction.contiguous(), t = target.contiguous();
  if (at::GradMode::is_enabled() && prediction.requires_grad()) return FusedSsimFunction::apply(p, t);
  return run_forward(p, t, /*with_derivatives=*/false).mean;
}

}  // namespace sfgs::ssim
