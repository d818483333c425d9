// CPU reference backend of the skinning op: skin_math.h's per-Gaussian steps in a parallel loop.
#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "skin/backend.h"
#include "skin/skin_math.h"

namespace sfgs::skin::cpu {
namespace {

constexpr int64_t kGrain = 2048;  // Gaussians per parallel task

template <typename T> const T* data_or_null(const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; }
template <typename T> T* mutable_or_null(const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; }

template <typename T> void forward_typed(const ForwardTensors& t) {
  const SkinArrays<T> s{t.joints.data_ptr<int32_t>(), t.weights.data_ptr<T>(), int(t.weights.size(1)),
                        t.weights.size(0),           t.transforms.data_ptr<T>(), t.canonical_means.data_ptr<T>(),
                        t.log_scales.data_ptr<T>(),  data_or_null<T>(t.rest),  t.means.data_ptr<T>(),
                        t.covariances.data_ptr<T>(), mutable_or_null<T>(t.posed_rest)};
  at::parallel_for(0, s.count, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) skin_one(s, i);
  });
}

template <typename T> void backward_typed(const BackwardTensors& t) {
  const SkinGradientArrays<T> g{t.joints.data_ptr<int32_t>(), t.weights.data_ptr<T>(),   int(t.weights.size(1)),
                                t.weights.size(0),           t.transforms.data_ptr<T>(), t.covariances.data_ptr<T>(),
                                data_or_null<T>(t.grad_means), data_or_null<T>(t.grad_covariances),
                                data_or_null<T>(t.grad_posed_rest), t.grad_canonical_means.data_ptr<T>(),
                                t.grad_log_scales.data_ptr<T>(),     mutable_or_null<T>(t.grad_rest)};
  at::parallel_for(0, g.count, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) skin_one_backward(g, i);
  });
}

}  // namespace

void forward(const ForwardTensors& t) {
  if (t.means.scalar_type() == at::kDouble) forward_typed<double>(t);
  else if (t.means.scalar_type() == at::kFloat) forward_typed<float>(t);
  else TORCH_CHECK(false, "skin_gaussians: tensors must be float32 or float64, got ", t.means.scalar_type());
}

void backward(const BackwardTensors& t) {
  if (t.covariances.scalar_type() == at::kDouble) backward_typed<double>(t);
  else backward_typed<float>(t);
}

}  // namespace sfgs::skin::cpu
