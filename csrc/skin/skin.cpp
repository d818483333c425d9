// The skinning op: validation at its boundary, the backend by device, and its one autograd node.
#include "skin/skin.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "common/tensor_description.h"
#include "skin/backend.h"
#include "skin/skin_math.h"

namespace sfgs::skin {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

void check_matrix(const at::Tensor& t, const char* name, int64_t rows, int64_t columns, const at::Tensor& like) {
  TORCH_CHECK(t.defined() && t.dim() == 2 && t.size(0) == rows && t.size(1) == columns, "skin_gaussians: ", name,
              " must have shape (", rows, ", ", columns, "), got ", describe(t));
  TORCH_CHECK(t.scalar_type() == like.scalar_type() && t.device() == like.device(), "skin_gaussians: ", name,
              " must be ", like.scalar_type(), " on ", like.device(), " like the weights, got ", describe(t));
}

template <typename T> void forward_as(const ForwardTensors& t) {
  const SkinArrays<T> arrays = arrays_of<T>(t);
  if (t.means.is_cuda())
    cuda::forward(arrays, t.means.device());
  else
    cpu::forward(arrays);
}

template <typename T> void backward_as(const BackwardTensors& t) {
  const SkinGradientArrays<T> arrays = arrays_of<T>(t);
  if (t.grad_canonical_means.is_cuda())
    cuda::backward(arrays, t.grad_canonical_means.device());
  else
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

// One node: canonical means, log-scales and (when given, as a non-empty tensor) rest points in; means,
// covariances and posed rest points out. LibTorch 1.13's custom functions take no undefined tensors: absent rest
// points travel as an empty tensor.
class SkinFunction : public torch::autograd::Function<SkinFunction> {
 public:
  static variable_list forward(AutogradContext* ctx, const at::Tensor& canonical_means, const at::Tensor& log_scales,
                               const at::Tensor& rest_or_empty, const at::Tensor& joints, const at::Tensor& weights,
                               const at::Tensor& transforms) {
    const bool has_rest = rest_or_empty.numel() > 0;
    ForwardTensors t;
    t.joints = joints;
    t.weights = weights;
    t.transforms = transforms;
    t.canonical_means = canonical_means;
    t.log_scales = log_scales;
    t.means = at::empty_like(canonical_means);
    t.covariances = at::empty({canonical_means.size(0), 6}, canonical_means.options());
    if (has_rest) {
      t.rest = rest_or_empty;
      t.posed_rest = at::empty_like(rest_or_empty);
    }
    dispatch_forward(t);
    ctx->save_for_backward({joints, weights, transforms, t.covariances});
    ctx->saved_data["has_rest"] = has_rest;
    return {t.means, t.covariances, has_rest ? t.posed_rest : at::empty_like(rest_or_empty)};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const bool has_rest = ctx->saved_data["has_rest"].toBool();
    BackwardTensors t;
    t.joints = saved[0];
    t.weights = saved[1];
    t.transforms = saved[2];
    t.covariances = saved[3];
    const int64_t n = t.covariances.size(0);
    if (grads[0].defined()) t.grad_means = grads[0].contiguous();
    if (grads[1].defined()) t.grad_covariances = grads[1].contiguous();
    if (has_rest && grads[2].defined()) {
      t.grad_posed_rest = grads[2].contiguous();
      t.grad_rest = at::empty({n, 3}, t.covariances.options());
    }
    t.grad_canonical_means = at::empty({n, 3}, t.covariances.options());
    t.grad_log_scales = at::empty({n}, t.covariances.options());
    dispatch_backward(t);
    return {t.grad_canonical_means, t.grad_log_scales, t.grad_rest, at::Tensor(), at::Tensor(), at::Tensor()};
  }
};

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
  TORCH_CHECK(!w.weights.is_cuda() || cuda::available(),
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
  if (transforms.requires_grad())
    return skinning_reference(w.to_dense(), transforms, canonical_means, log_scales, rest);
  const at::Tensor rows = transforms.narrow(1, 0, 3).reshape({j, kTransformValues}).contiguous();
  const at::Tensor rest_or_empty = rest.defined() ? rest.contiguous() : at::empty({0, 3}, canonical_means.options());
  const variable_list out = SkinFunction::apply(canonical_means.contiguous(), log_scales.contiguous(), rest_or_empty,
                                                w.joints.contiguous(), w.weights.contiguous(), rows);
  return SkinnedGaussians{out[0], out[1], rest.defined() ? out[2] : at::Tensor()};
}

bool cuda_available() { return cuda::available(); }

}  // namespace sfgs::skin
