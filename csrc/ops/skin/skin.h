#pragma once
// sfgs's fused skinning op: linear blend skinning of isotropic Gaussians (means and packed covariances, and
// optionally the body's rest points) in one pass, on a CPU reference backend and a CUDA kernel chosen by the
// tensors' device, with one autograd node. It replaces the
// dozen LibTorch operations of the reference composition (skinning_reference), which it is tested against, and
// reads each Gaussian's few influencing joints instead of a dense (N, J) weight row. docs/performance.md.
#include <ATen/core/Tensor.h>

namespace sfgs::skin {

// Skinning weights as each row's influences: the joints with a non-zero weight, padded with weight 0.
struct SkinningWeights {
  at::Tensor joints;        // (N, K) int32
  at::Tensor weights;       // (N, K) floating
  int64_t joint_count = 0;  // J of the dense weights they came from

  // From dense (N, J) weights (any floating dtype, device); K is the largest number of non-zero weights of a row.
  static SkinningWeights from_dense(const at::Tensor& dense);
  // The same weights in `dtype` on `device` (joints stay int32).
  SkinningWeights to(at::Device device, at::ScalarType dtype) const;
  at::Tensor to_dense() const;  // (N, J)
};

struct SkinnedGaussians {
  at::Tensor means;        // (N, 3)
  at::Tensor covariances;  // (N, 6) packed (xx, xy, xz, yy, yz, zz) of exp(2 s) A A^T
  at::Tensor posed_rest;   // (N, 3) the rest points carried by the same transforms; undefined when no rest
                           // points were given
};

// transforms (J, 4, 4): rest -> posed per joint (the last row is not read); canonical_means (N, 3); log_scales (N);
// rest (N, 3) or undefined. All of one floating dtype and on the weights' device. The fused node differentiates
// canonical_means, log_scales, rest and, when they require a gradient (a pose being fitted; at most
// kMaxJointsWithTransformGradient joints, ops/skin/skin_math.h), the transforms.
SkinnedGaussians skin_gaussians(const SkinningWeights& weights, const at::Tensor& transforms,
                                const at::Tensor& canonical_means, const at::Tensor& log_scales,
                                const at::Tensor& rest = {});

// The same result composed of LibTorch operations on the dense weights (what the op is tested against).
SkinnedGaussians skinning_reference(const at::Tensor& dense_weights, const at::Tensor& transforms,
                                    const at::Tensor& canonical_means, const at::Tensor& log_scales,
                                    const at::Tensor& rest = {});

// Whether this build has the CUDA kernel.
bool cuda_available();

}  // namespace sfgs::skin
