#pragma once
// sfgs's fused GroupNorm + affine + ReLU: relu(gamma * GroupNorm_G(pre + bias) + beta) over the rows of an (N, C)
// matrix, the activation of every hidden layer of the avatar's GroupNorm MLPs (model/mlp.h). LibTorch composes it
// of about a dozen operations, each a pass over the (N, C) activations, and differentiates it with as many again,
// several of them reductions over N; at 216k points and C = 128 those were the largest share of a training step
// (docs/performance.md). Here it is one pass forward and one backward (a CPU backend and a CUDA kernel chosen by the
// device, one autograd node), and the layer's bias is folded in so that its gradient comes from the same pass.
// group_norm_relu_reference is the LibTorch composition it is tested against. docs/avatar.md.
#include <cstdint>

#include <ATen/core/Tensor.h>
#include "ops/group_norm/constants.h"

namespace sfgs::group_norm {

// pre (N, C); bias (C) or undefined; gamma, beta (C); all of one floating dtype and device, C a multiple of
// `groups`. Differentiable in pre, bias, gamma and beta (once: no second derivative). The CUDA kernel takes group
// sizes that are multiples of 32 up to kGroupNormMaxChannels channels; other shapes on CUDA take the reference.
at::Tensor group_norm_relu(const at::Tensor& pre, const at::Tensor& bias, const at::Tensor& gamma,
                           const at::Tensor& beta, int64_t groups, double epsilon);

// relu(gamma * GroupNorm_G(x weight^T + bias) + beta): a hidden layer with its linear map, x (N, I), weight (C, I).
// The product is not kept for the backward but recomputed there (one matrix product, tens of microseconds at 216k
// points), which saves an (N, C) activation of training memory per layer. Differentiable in x, weight, bias, gamma
// and beta.
at::Tensor linear_group_norm_relu(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias,
                                  const at::Tensor& gamma, const at::Tensor& beta, int64_t groups, double epsilon);

// The same function as LibTorch operations (differentiable by autograd): the groups' moments written out.
at::Tensor group_norm_relu_reference(const at::Tensor& pre, const at::Tensor& bias, const at::Tensor& gamma,
                                     const at::Tensor& beta, int64_t groups, double epsilon);

// Whether inputs of this shape on this device run fused (the CPU backend always does).
bool fuses(const at::Tensor& pre, int64_t groups);

}  // namespace sfgs::group_norm
