#pragma once
// The contract between the skinning op (csrc/skin/skin.cpp: validation, autograd) and its two backends
// (csrc/cpu/skin_cpu.cpp, csrc/cuda/skin_cuda.cpp). Tensors arrive validated, contiguous, of one floating dtype
// and on one device; outputs are allocated by the op.
#include <ATen/core/Tensor.h>

namespace sfgs::skin {

struct ForwardTensors {
  at::Tensor joints, weights, transforms;  // (N, K) int32, (N, K), (J, 12)
  at::Tensor canonical_means, log_scales, rest;  // rest may be undefined
  at::Tensor means, covariances, posed_rest;     // outputs; posed_rest defined with rest
};

struct BackwardTensors {
  at::Tensor joints, weights, transforms, covariances;  // the forward's, covariances its output
  at::Tensor grad_means, grad_covariances, grad_posed_rest;  // any may be undefined
  at::Tensor grad_canonical_means, grad_log_scales;          // outputs
  at::Tensor grad_rest;                                      // output, defined with grad_posed_rest
};

namespace cpu {
void forward(const ForwardTensors& t);
void backward(const BackwardTensors& t);
}  // namespace cpu

namespace cuda {
bool available();
void forward(const ForwardTensors& t);
void backward(const BackwardTensors& t);
}  // namespace cuda

}  // namespace sfgs::skin
