#pragma once
// The splatting op as a dispatcher operator, sfgs::render_gaussians (registered in op.cpp): CPU and CUDA kernels,
// a Meta kernel that only describes the outputs, and an Autograd kernel, the op's one autograd node. sfgs::render()
// and torch.ops.sfgs.render_gaussians both go through it.
#include <tuple>

#include <ATen/core/Tensor.h>

#include "ops/splat/backend.h"
#include "ops/splat/splat.h"

namespace sfgs::splat {

// image (H, W, C), alpha (H, W), depth (H, W), radii (N, 2) int32.
using RenderOutputs = std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor>;

// Calls the op through the dispatcher, autograd included. Undefined tensors of `tensors` are passed as None.
// `budget` (may be null) sizes a CUDA pass's buffers without a host read (splat.h); the schema has no place for it
// (torch.ops callers render eagerly), so it reaches the CUDA kernel below the dispatcher through a scope this call
// opens on its thread. (Referencing this keeps op.cpp, and with it the registration, in a static link.)
RenderOutputs render_gaussians(const SplatInputs& tensors, const Camera& camera, double low_pass_variance,
                               bool antialiased, bool deterministic, const BinningBudget* budget = nullptr);

}  // namespace sfgs::splat
