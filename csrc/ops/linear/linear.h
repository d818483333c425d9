#pragma once
// The networks' linear layer (model/mlp.h): x weight^T + bias, forward as at::linear (one matrix product with the
// bias in its epilogue), backward with the bias's gradient as sfgs's own column sum over the rows. LibTorch's
// reduction of a (216k, 128) gradient to its 128 column sums ran at about a seventh of an H200's memory bandwidth
// (0.19 ms, five times a pass over the rows; docs/performance.md); the column sum here is a two-pass, deterministic
// kernel. One autograd node; the CPU sums with at::sum.
#include <ATen/core/Tensor.h>

namespace sfgs::linear {

// x (N, I), weight (O, I), bias (O) or undefined; one floating dtype and device. Differentiable in all three (once).
at::Tensor linear(const at::Tensor& x, const at::Tensor& weight, const at::Tensor& bias);

// The sums of the columns of a (R, C) matrix -> (C), in a fixed order (the same result every run). Not
// differentiable: it serves backward passes (this layer's, the fused GroupNorm's partial rows).
at::Tensor column_sum(const at::Tensor& rows);

}  // namespace sfgs::linear
