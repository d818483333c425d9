// The skinning op: validation at its boundary, and its dispatcher registration (ops/registration.h): the CPU and CUDA
// kernels route to the backend by device, the Meta kernels describe the outputs, the Autograd kernel is its one node.
#include "ops/skin/skin.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/registration.h"
#include "ops/skin/backend.h"
#include "ops/skin/skin_math.h"

namespace sfgs::skin {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

void check_matrix(const at::Tensor& t, const char* name, int64_t rows, int64_t columns, const at::Tensor& like) {
  TORCH_CHECK(t.defined() && t.dim() == 2 && t.size(0) == rows && t.size(1) == columns, "sfgs::skin_gaussians: ", name,
              " must have shape (", rows, ", ", columns, "), got ", describe(t));
  TORCH_CHECK(t.scalar_type() == like.scalar_type() && t.device() == like.device(), "sfgs::skin_gaussians: ", name,
              " must be ", like.scalar_type(), " on ", like.device(), " like the weights, got ", describe(t));
}

template <typename T> void forward_as(const ForwardTensors& t) {
  const SkinArrays<T> arrays = arrays_of<T>(t);
#if defined(SFGS_WITH_CUDA)
  if (t.means.is_cuda()) return cuda::forward(arrays, t.means.device());
#endif
  cpu::forward(arrays);
}

template <typename T> void backward_as(const BackwardTensors& t) {
  const SkinGradientArrays<T> arrays = arrays_of<T>(t);
#if defined(SFGS_WITH_CUDA)
  if (t.grad_canonical_means.is_cuda()) return cuda::backward(arrays, t.grad_canonical_means.device());
#endif
  cpu::backward(arrays);
}

void dispatch_forward(const ForwardTensors& t) {
  if (t.means.scalar_type() == at::kDouble)
    forward_as<double>(t);
  else if (t.means.scalar_type() == at::kFloat)
    forward_as<float>(t);
  else
    TORCH_CHECK(false, "skin_gaussians: tensors must be float32 or float64, got ", t.means.scalar_type());
}

void dispatch_backward(const BackwardTensors& t) {
  if (t.covariances.scalar_type() == at::kDouble)
    backward_as<double>(t);
  else
    backward_as<float>(t);
}

using ops::optional_tensor;
using ops::OptionalTensor;
using Outputs = std::tuple<at::Tensor, at::Tensor, at::Tensor>;
using GradientOutputs = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor>;

constexpr const char* kForwardSchema =
    "skin_gaussians(Tensor canonical_means, Tensor log_scales, Tensor? rest, Tensor joints, Tensor weights, "
    "Tensor transform_rows) -> (Tensor means, Tensor covariances, Tensor posed_rest)";
// With canonical_means and log_scales (and rest, where the forward had it) the backward also returns the transform
// rows' gradient (J, 12); without them an empty (0, 12).
constexpr const char* kBackwardSchema =
    "skin_gaussians_backward(Tensor joints, Tensor weights, Tensor transform_rows, Tensor covariances, "
    "Tensor? grad_means, Tensor? grad_covariances, Tensor? grad_posed_rest, Tensor? canonical_means, "
    "Tensor? log_scales, Tensor? rest) "
    "-> (Tensor grad_canonical_means, Tensor grad_log_scales, Tensor grad_rest, Tensor grad_transform_rows)";
using ForwardSignature = Outputs(const at::Tensor&, const at::Tensor&, const OptionalTensor&, const at::Tensor&,
                                 const at::Tensor&, const at::Tensor&);
using BackwardSignature = GradientOutputs(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                          const OptionalTensor&, const OptionalTensor&, const OptionalTensor&,
                                          const OptionalTensor&, const OptionalTensor&, const OptionalTensor&);

// The kernels' own checks (torch.ops.sfgs reaches them without skin_gaussians'): shapes, dtypes and one device.
// A joint index out of range is not read (it makes its Gaussian NaN: skin_math.h), so no host read is needed.
void check_weights_and_transforms(const at::Tensor& joints, const at::Tensor& weights,
                                  const at::Tensor& transform_rows) {
  TORCH_CHECK(weights.dim() == 2 && at::isFloatingType(weights.scalar_type()),
              "sfgs::skin_gaussians: weights must be a floating (N, K) tensor, got ", describe(weights));
  TORCH_CHECK(
      joints.sizes() == weights.sizes() && joints.scalar_type() == at::kInt && joints.device() == weights.device(),
      "sfgs::skin_gaussians: joints must be an int32 (", weights.size(0), ", ", weights.size(1), ") tensor on ",
      weights.device(), ", got ", describe(joints));
  TORCH_CHECK(transform_rows.dim() == 2, "sfgs::skin_gaussians: transform_rows must be (J, ", kTransformValues,
              "), got ", describe(transform_rows));
  check_matrix(transform_rows, "transform_rows", transform_rows.size(0), kTransformValues, weights);
}

void check_forward_arguments(const at::Tensor& canonical_means, const at::Tensor& log_scales,
                             const OptionalTensor& rest, const at::Tensor& joints, const at::Tensor& weights,
                             const at::Tensor& transform_rows) {
  check_weights_and_transforms(joints, weights, transform_rows);
  const int64_t n = weights.size(0);
  check_matrix(canonical_means, "canonical_means", n, 3, weights);
  check_matrix(log_scales.unsqueeze(1), "log_scales", n, 1, weights);
  if (rest.has_value()) check_matrix(*rest, "rest", n, 3, weights);
}

// Without rest points the posed rest points (and their gradient) are an empty (0, 3) tensor: a schema's outputs are
// tensors.
ForwardTensors forward_tensors(const at::Tensor& canonical_means, const at::Tensor& log_scales,
                               const OptionalTensor& rest, const at::Tensor& joints, const at::Tensor& weights,
                               const at::Tensor& transform_rows) {
  ForwardTensors t;
  t.joints = joints.contiguous();
  t.weights = weights.contiguous();
  t.transforms = transform_rows.contiguous();
  t.canonical_means = canonical_means.contiguous();
  t.log_scales = log_scales.contiguous();
  t.means = at::empty_like(canonical_means);
  t.covariances = at::empty({canonical_means.size(0), 6}, canonical_means.options());
  if (rest.has_value()) {
    t.rest = rest->contiguous();
    t.posed_rest = at::empty_like(*rest);
  }
  return t;
}

at::Tensor or_empty_points(const at::Tensor& points, const at::Tensor& like) {
  return points.defined() ? points : at::empty({0, 3}, like.options());
}

Outputs forward_kernel(const at::Tensor& canonical_means, const at::Tensor& log_scales, const OptionalTensor& rest,
                       const at::Tensor& joints, const at::Tensor& weights, const at::Tensor& transform_rows) {
  check_forward_arguments(canonical_means, log_scales, rest, joints, weights, transform_rows);
  const ForwardTensors t = forward_tensors(canonical_means, log_scales, rest, joints, weights, transform_rows);
  dispatch_forward(t);
  return {t.means, t.covariances, or_empty_points(t.posed_rest, t.means)};
}

Outputs forward_meta(const at::Tensor& canonical_means, const at::Tensor& log_scales, const OptionalTensor& rest,
                     const at::Tensor& joints, const at::Tensor& weights, const at::Tensor& transform_rows) {
  check_forward_arguments(canonical_means, log_scales, rest, joints, weights, transform_rows);
  const ForwardTensors t = forward_tensors(canonical_means, log_scales, rest, joints, weights, transform_rows);
  return {t.means, t.covariances, or_empty_points(t.posed_rest, t.means)};
}

// The backward's arguments; `inputs` (canonical_means, log_scales, rest) are given for the transforms' gradient.
struct TransformGradientInputs {
  const OptionalTensor& canonical_means;
  const OptionalTensor& log_scales;
  const OptionalTensor& rest;
};

void check_backward_arguments(const at::Tensor& joints, const at::Tensor& weights, const at::Tensor& transform_rows,
                              const at::Tensor& covariances, const OptionalTensor& grad_means,
                              const OptionalTensor& grad_covariances, const OptionalTensor& grad_posed_rest,
                              const TransformGradientInputs& inputs) {
  check_weights_and_transforms(joints, weights, transform_rows);
  const int64_t n = weights.size(0);
  check_matrix(covariances, "covariances", n, 6, weights);
  if (grad_means.has_value()) check_matrix(*grad_means, "grad_means", n, 3, weights);
  if (grad_covariances.has_value()) check_matrix(*grad_covariances, "grad_covariances", n, 6, weights);
  if (grad_posed_rest.has_value()) check_matrix(*grad_posed_rest, "grad_posed_rest", n, 3, weights);
  TORCH_CHECK(inputs.canonical_means.has_value() == inputs.log_scales.has_value(),
              "sfgs::skin_gaussians_backward: the transforms' gradient takes both canonical_means and log_scales");
  if (inputs.rest.has_value())
    TORCH_CHECK(inputs.canonical_means.has_value(),
                "sfgs::skin_gaussians_backward: rest is read only for the transforms' gradient, with canonical_means");
  if (!inputs.canonical_means.has_value()) return;
  check_matrix(*inputs.canonical_means, "canonical_means", n, 3, weights);
  check_matrix(inputs.log_scales->unsqueeze(1), "log_scales", n, 1, weights);
  if (inputs.rest.has_value()) check_matrix(*inputs.rest, "rest", n, 3, weights);
  TORCH_CHECK(transform_rows.size(0) <= kMaxJointsWithTransformGradient,
              "sfgs::skin_gaussians_backward: the transforms' gradient takes at most ", kMaxJointsWithTransformGradient,
              " joints, got ", transform_rows.size(0));
}

BackwardTensors backward_tensors(const at::Tensor& joints, const at::Tensor& weights, const at::Tensor& transform_rows,
                                 const at::Tensor& covariances, const OptionalTensor& grad_means,
                                 const OptionalTensor& grad_covariances, const OptionalTensor& grad_posed_rest,
                                 const TransformGradientInputs& inputs) {
  BackwardTensors t;
  t.joints = joints.contiguous();
  t.weights = weights.contiguous();
  t.transforms = transform_rows.contiguous();
  t.covariances = covariances.contiguous();
  const int64_t n = covariances.size(0);
  if (grad_means.has_value()) t.grad_means = grad_means->contiguous();
  if (grad_covariances.has_value()) t.grad_covariances = grad_covariances->contiguous();
  if (grad_posed_rest.has_value()) {
    t.grad_posed_rest = grad_posed_rest->contiguous();
    t.grad_rest = at::empty({n, 3}, covariances.options());
  }
  t.grad_canonical_means = at::empty({n, 3}, covariances.options());
  t.grad_log_scales = at::empty({n}, covariances.options());
  if (inputs.canonical_means.has_value()) {
    t.canonical_means = inputs.canonical_means->contiguous();
    t.log_scales = inputs.log_scales->contiguous();
    if (inputs.rest.has_value()) t.rest = inputs.rest->contiguous();
    t.grad_transforms = at::empty({transform_rows.size(0), kTransformValues}, covariances.options());
  }
  return t;
}

GradientOutputs gradient_outputs(const BackwardTensors& t) {
  return {t.grad_canonical_means, t.grad_log_scales, or_empty_points(t.grad_rest, t.covariances),
          t.grad_transforms.defined() ? t.grad_transforms : at::empty({0, kTransformValues}, t.covariances.options())};
}

// The backward's arguments checked and its outputs allocated: what both the backend and the Meta kernel start from.
BackwardTensors checked_backward_tensors(const at::Tensor& joints, const at::Tensor& weights,
                                         const at::Tensor& transform_rows, const at::Tensor& covariances,
                                         const OptionalTensor& grad_means, const OptionalTensor& grad_covariances,
                                         const OptionalTensor& grad_posed_rest, const OptionalTensor& canonical_means,
                                         const OptionalTensor& log_scales, const OptionalTensor& rest) {
  const TransformGradientInputs inputs{canonical_means, log_scales, rest};
  check_backward_arguments(joints, weights, transform_rows, covariances, grad_means, grad_covariances, grad_posed_rest,
                           inputs);
  return backward_tensors(joints, weights, transform_rows, covariances, grad_means, grad_covariances, grad_posed_rest,
                          inputs);
}

GradientOutputs backward_kernel(const at::Tensor& joints, const at::Tensor& weights, const at::Tensor& transform_rows,
                                const at::Tensor& covariances, const OptionalTensor& grad_means,
                                const OptionalTensor& grad_covariances, const OptionalTensor& grad_posed_rest,
                                const OptionalTensor& canonical_means, const OptionalTensor& log_scales,
                                const OptionalTensor& rest) {
  const BackwardTensors t =
      checked_backward_tensors(joints, weights, transform_rows, covariances, grad_means, grad_covariances,
                               grad_posed_rest, canonical_means, log_scales, rest);
  dispatch_backward(t);
  return gradient_outputs(t);
}

GradientOutputs backward_meta(const at::Tensor& joints, const at::Tensor& weights, const at::Tensor& transform_rows,
                              const at::Tensor& covariances, const OptionalTensor& grad_means,
                              const OptionalTensor& grad_covariances, const OptionalTensor& grad_posed_rest,
                              const OptionalTensor& canonical_means, const OptionalTensor& log_scales,
                              const OptionalTensor& rest) {
  return gradient_outputs(checked_backward_tensors(joints, weights, transform_rows, covariances, grad_means,
                                                   grad_covariances, grad_posed_rest, canonical_means, log_scales,
                                                   rest));
}

const c10::TypedOperatorHandle<ForwardSignature>& forward_op() {
  static const auto handle = ops::find_op<ForwardSignature>("sfgs::skin_gaussians");
  return handle;
}
const c10::TypedOperatorHandle<BackwardSignature>& backward_op() {
  static const auto handle = ops::find_op<BackwardSignature>("sfgs::skin_gaussians_backward");
  return handle;
}

// The op's one autograd node: canonical means, log-scales, rest points (when given) and the transform rows (a pose
// being fitted) are differentiated; the weights are not.
class SkinFunction : public torch::autograd::Function<SkinFunction> {
 public:
  static variable_list forward(AutogradContext* ctx, const at::Tensor& canonical_means, const at::Tensor& log_scales,
                               const OptionalTensor& rest, const at::Tensor& joints, const at::Tensor& weights,
                               const at::Tensor& transform_rows) {
    Outputs out;
    {
      const at::AutoDispatchBelowADInplaceOrView below_autograd;
      out = forward_op().call(canonical_means, log_scales, rest, joints, weights, transform_rows);
    }
    const auto& [means, covariances, posed_rest] = out;
    // The transforms' gradient reads the forward's inputs; otherwise they are not kept.
    const bool transforms_differentiated = transform_rows.requires_grad();
    const at::Tensor undefined;
    ctx->save_for_backward({joints, weights, transform_rows, covariances,
                            transforms_differentiated ? canonical_means : undefined,
                            transforms_differentiated ? log_scales : undefined,
                            transforms_differentiated && rest.has_value() ? *rest : undefined});
    ctx->saved_data["has_rest"] = rest.has_value();
    ctx->set_materialize_grads(false);
    return {means, covariances, posed_rest};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const bool has_rest = ctx->saved_data["has_rest"].toBool();
    const bool transforms_wanted = saved[4].defined();  // the transform rows required a gradient
    const auto [grad_canonical_means, grad_log_scales, grad_rest, grad_transform_rows] =
        backward_op().call(saved[0], saved[1], saved[2], saved[3], optional_tensor(grads[0]), optional_tensor(grads[1]),
                           has_rest ? optional_tensor(grads[2]) : c10::nullopt,
                           transforms_wanted ? optional_tensor(saved[4]) : c10::nullopt,
                           transforms_wanted ? optional_tensor(saved[5]) : c10::nullopt,
                           transforms_wanted ? optional_tensor(saved[6]) : c10::nullopt);
    return {grad_canonical_means, grad_log_scales, has_rest && grad_rest.numel() > 0 ? grad_rest : at::Tensor(),
            at::Tensor(),         at::Tensor(),    transforms_wanted ? grad_transform_rows : at::Tensor()};
  }
};

Outputs autograd_kernel(const at::Tensor& canonical_means, const at::Tensor& log_scales, const OptionalTensor& rest,
                        const at::Tensor& joints, const at::Tensor& weights, const at::Tensor& transform_rows) {
  const variable_list out = SkinFunction::apply(canonical_means, log_scales, rest, joints, weights, transform_rows);
  return {out[0], out[1], out[2]};
}

}  // namespace

SkinningWeights SkinningWeights::from_dense(const at::Tensor& dense) {
  TORCH_CHECK(dense.defined() && dense.dim() == 2 && at::isFloatingType(dense.scalar_type()) && dense.size(1) > 0,
              "SkinningWeights: dense weights must be a floating (N, J) tensor with J >= 1, got ", describe(dense));
  const at::Tensor used = dense != 0;
  const int64_t influences = dense.size(0) > 0 ? std::max<int64_t>(1, used.sum(1).max().item<int64_t>()) : 1;
  // topk keeps every non-zero weight (at most `influences` per row); the rest of a row's picks are zeros.
  const auto [values, joints] = dense.abs().topk(influences, 1);
  SkinningWeights w;
  w.weights = dense.gather(1, joints).contiguous();
  w.joints = joints.to(at::kInt).contiguous();
  w.joint_count = dense.size(1);
  return w;
}

SkinningWeights SkinningWeights::to(at::Device device, at::ScalarType dtype) const {
  return SkinningWeights{joints.to(device), weights.to(device, dtype), joint_count};
}

at::Tensor SkinningWeights::to_dense() const {
  return at::zeros({weights.size(0), joint_count}, weights.options()).scatter_add_(1, joints.to(at::kLong), weights);
}

SkinnedGaussians skinning_reference(const at::Tensor& dense_weights, const at::Tensor& transforms,
                                    const at::Tensor& canonical_means, const at::Tensor& log_scales,
                                    const at::Tensor& rest) {
  const int64_t n = dense_weights.size(0), j = dense_weights.size(1);
  const at::Tensor blended = dense_weights.matmul(transforms.narrow(1, 0, 3).reshape({j, 12})).view({n, 3, 4});
  const at::Tensor a = blended.narrow(2, 0, 3), t = blended.select(2, 3);
  const auto apply = [&](const at::Tensor& points) { return (a * points.unsqueeze(1)).sum(-1) + t; };
  const at::Tensor gram = a.matmul(a.transpose(1, 2)).view({n, 9});  // row-major A A^T
  const at::Tensor upper = at::stack({gram.select(1, 0), gram.select(1, 1), gram.select(1, 2), gram.select(1, 4),
                                      gram.select(1, 5), gram.select(1, 8)},
                                     1);
  SkinnedGaussians out;
  out.means = apply(canonical_means);
  out.covariances = upper * (2 * log_scales).exp().unsqueeze(1);
  if (rest.defined()) out.posed_rest = apply(rest);
  return out;
}

SkinnedGaussians skin_gaussians(const SkinningWeights& w, const at::Tensor& transforms,
                                const at::Tensor& canonical_means, const at::Tensor& log_scales,
                                const at::Tensor& rest) {
  TORCH_CHECK(w.weights.defined() && w.weights.dim() == 2 && at::isFloatingType(w.weights.scalar_type()),
              "skin_gaussians: weights must be a floating (N, K) tensor, got ", describe(w.weights));
  const int64_t n = w.weights.size(0), k = w.weights.size(1), j = w.joint_count;
  TORCH_CHECK(w.weights.is_cpu() || w.weights.is_cuda(),
              "skin_gaussians: tensors must be on the CPU or a CUDA "
              "device, got ",
              describe(w.weights));
  TORCH_CHECK(!w.weights.is_cuda() || ops::kBuiltWithCuda,
              "skin_gaussians: got CUDA tensors but this build of sfgs has no CUDA backend");
  TORCH_CHECK(w.joints.defined() && w.joints.sizes() == w.weights.sizes() && w.joints.scalar_type() == at::kInt &&
                  w.joints.device() == w.weights.device(),
              "skin_gaussians: the weights' joints must be an int32 (", n, ", ", k, ") tensor on ", w.weights.device(),
              ", got ", describe(w.joints));
  TORCH_CHECK(transforms.defined() && transforms.dim() == 3 && transforms.size(0) == j && transforms.size(1) == 4 &&
                  transforms.size(2) == 4,
              "skin_gaussians: transforms must have shape (", j, ", 4, 4), got ", describe(transforms));
  check_matrix(transforms.reshape({j, 16}), "transforms", j, 16, w.weights);
  check_matrix(canonical_means, "canonical_means", n, 3, w.weights);
  check_matrix(log_scales.unsqueeze(1), "log_scales", n, 1, w.weights);
  if (rest.defined()) check_matrix(rest, "rest", n, 3, w.weights);
  TORCH_CHECK(!transforms.requires_grad() || j <= kMaxJointsWithTransformGradient,
              "skin_gaussians: the transforms' gradient takes at most ", kMaxJointsWithTransformGradient,
              " joints, got ", j);
  // A pose being fitted differentiates the transforms: the rows' gradient flows back through this view.
  const at::Tensor rows = transforms.narrow(1, 0, 3).reshape({j, kTransformValues}).contiguous();
  const auto [means, covariances, posed_rest] =
      forward_op().call(canonical_means.contiguous(), log_scales.contiguous(), optional_tensor(rest),
                        w.joints.contiguous(), w.weights.contiguous(), rows);
  return SkinnedGaussians{means, covariances, rest.defined() ? posed_rest : at::Tensor()};
}

bool cuda_available() { return ops::kBuiltWithCuda; }

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kForwardSchema);
  m.def(kBackwardSchema);
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("skin_gaussians", TORCH_FN(forward_kernel));
  m.impl("skin_gaussians_backward", TORCH_FN(backward_kernel));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("skin_gaussians", TORCH_FN(forward_kernel));
  m.impl("skin_gaussians_backward", TORCH_FN(backward_kernel));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("skin_gaussians", TORCH_FN(forward_meta));
  m.impl("skin_gaussians_backward", TORCH_FN(backward_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("skin_gaussians", TORCH_FN(autograd_kernel)); }

}  // namespace sfgs::skin
