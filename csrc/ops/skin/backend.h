#pragma once
// The contract between the skinning op (csrc/ops/skin/skin.cpp: validation, autograd) and its two backends
// (csrc/ops/skin/skin_cpu.cpp, csrc/ops/skin/skin_cuda.cpp). Tensors arrive validated, contiguous, of one floating
// dtype and on one device; outputs are allocated by the op, which picks the dtype and hands the backends raw arrays.
#include <ATen/core/Tensor.h>

#include "ops/skin/skin_math.h"

namespace sfgs::skin {

struct ForwardTensors {
  at::Tensor joints, weights, transforms;        // (N, K) int32, (N, K), (J, 12)
  at::Tensor canonical_means, log_scales, rest;  // rest may be undefined
  at::Tensor means, covariances, posed_rest;     // outputs; posed_rest defined with rest
};

struct BackwardTensors {
  at::Tensor joints, weights, transforms, covariances;       // the forward's, covariances its output
  at::Tensor grad_means, grad_covariances, grad_posed_rest;  // any may be undefined
  at::Tensor grad_canonical_means, grad_log_scales;          // outputs
  at::Tensor grad_rest;                                      // output, defined with grad_posed_rest
  // The transforms' gradient: the forward's inputs (rest may be undefined) and the (J, 12) output, all defined
  // exactly when it is wanted.
  at::Tensor canonical_means, log_scales, rest, grad_transforms;
};

// The tensors as the raw arrays of skin_math.h in their dtype T, built once here for both backends.
template <typename T> const T* data_or_null(const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; }
template <typename T> T* mutable_data_or_null(const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; }

template <typename T> SkinArrays<T> arrays_of(const ForwardTensors& t) {
  return SkinArrays<T>{t.joints.data_ptr<int32_t>(),    t.weights.data_ptr<T>(),
                       int(t.weights.size(1)),          t.weights.size(0),
                       t.transforms.data_ptr<T>(),      t.transforms.size(0),
                       t.canonical_means.data_ptr<T>(), t.log_scales.data_ptr<T>(),
                       data_or_null<T>(t.rest),         t.means.data_ptr<T>(),
                       t.covariances.data_ptr<T>(),     mutable_data_or_null<T>(t.posed_rest)};
}

template <typename T> SkinGradientArrays<T> arrays_of(const BackwardTensors& t) {
  return SkinGradientArrays<T>{t.joints.data_ptr<int32_t>(),
                               t.weights.data_ptr<T>(),
                               int(t.weights.size(1)),
                               t.weights.size(0),
                               t.transforms.data_ptr<T>(),
                               t.transforms.size(0),
                               t.covariances.data_ptr<T>(),
                               data_or_null<T>(t.grad_means),
                               data_or_null<T>(t.grad_covariances),
                               data_or_null<T>(t.grad_posed_rest),
                               t.grad_canonical_means.data_ptr<T>(),
                               t.grad_log_scales.data_ptr<T>(),
                               mutable_data_or_null<T>(t.grad_rest),
                               data_or_null<T>(t.canonical_means),
                               data_or_null<T>(t.log_scales),
                               data_or_null<T>(t.rest),
                               mutable_data_or_null<T>(t.grad_transforms)};
}

// The transforms' gradient is summed in fixed chunks of Gaussians, then chunk by chunk: the same bits for any number
// of threads.
namespace cpu {
void forward(const SkinArrays<float>& arrays);
void forward(const SkinArrays<double>& arrays);
void backward(const SkinGradientArrays<float>& arrays);
void backward(const SkinGradientArrays<double>& arrays);
}  // namespace cpu

// On `device`'s current stream. The transforms' gradient takes a scratch buffer of per-block sums from the caching
// allocator.
namespace cuda {
void forward(const SkinArrays<float>& arrays, at::Device device);
void forward(const SkinArrays<double>& arrays, at::Device device);
void backward(const SkinGradientArrays<float>& arrays, at::Device device);
void backward(const SkinGradientArrays<double>& arrays, at::Device device);
}  // namespace cuda

}  // namespace sfgs::skin
