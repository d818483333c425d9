#pragma once
// Forward kinematics over a joint tree and linear blend skinning, shared by the SMPL-X and MANO layers.
#include <cstdint>
#include <vector>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

namespace sfgs::body {

// The base of the body-model modules. torch::nn::Module::to(dtype) casts every buffer, integer index buffers
// included; these modules cast only their floating-point buffers and move all of them.
class BodyModule : public torch::nn::Module {
 public:
  using torch::nn::Module::to;
  void to(torch::Device device, torch::Dtype dtype, bool non_blocking = false) override;
  void to(torch::Dtype dtype, bool non_blocking = false) override;
};

struct PosedSkeleton {
  at::Tensor joints;               // (B, J, 3) posed joint positions
  at::Tensor joint_transforms;     // (B, J, 4, 4) world frame of each joint: posed rotation and position
  at::Tensor skinning_transforms;  // (B, J, 4, 4) maps a rest-pose point rigidly attached to joint j to its pose
};

// A joint tree with parents[0] = -1 and 0 <= parents[j] < j otherwise (the SMPL-family order). Joints of equal
// depth are composed in one batched step: the 55-joint SMPL-X tree takes 10 steps instead of 54. On CUDA, for
// float32 inputs none of which requires a gradient (every frame of inference, and training without pose
// refinement), the whole chain is one fused kernel (csrc/cuda/kinematic_chain.cu) instead of some 80 small
// launches; that LibTorch composition is its reference.
class KinematicTreeImpl : public BodyModule {
 public:
  explicit KinematicTreeImpl(std::vector<int64_t> parents);

  int64_t size() const { return static_cast<int64_t>(parents_.size()); }
  const std::vector<int64_t>& parents() const { return parents_; }
  // Whether `joint` is `ancestor` or lies below it.
  bool in_subtree(int64_t ancestor, int64_t joint) const;

  // Local joint rotations (B, J, 3, 3) about rest joints (B, J, 3); `translation` (B, 3) moves the root.
  PosedSkeleton pose(const at::Tensor& rotations, const at::Tensor& rest_joints, const at::Tensor& translation) const;
  // The LibTorch composition (differentiable, any dtype and device): what pose() runs when it does not fuse.
  PosedSkeleton pose_reference(const at::Tensor& rotations, const at::Tensor& rest_joints,
                               const at::Tensor& translation) const;
  // Whether pose() takes the fused kernel for these inputs.
  bool fuses(const at::Tensor& rotations, const at::Tensor& rest_joints, const at::Tensor& translation) const;

 private:
  void check_pose_inputs(const at::Tensor& rotations, const at::Tensor& rest_joints,
                         const at::Tensor& translation) const;
  // The two paths of pose(), on checked inputs: the fused kernel and the LibTorch composition.
  PosedSkeleton pose_fused(const at::Tensor& rotations, const at::Tensor& rest_joints,
                           const at::Tensor& translation) const;
  PosedSkeleton compose(const at::Tensor& rotations, const at::Tensor& rest_joints,
                        const at::Tensor& translation) const;

  std::vector<int64_t> parents_;
  // Per depth level >= 1: its joints, and where their parents sit in the depth-ordered concatenation.
  std::vector<at::Tensor> level_joints_, level_parent_slots_;
  at::Tensor root_, parent_or_self_, depth_order_inverse_;
  // parents_ as int32 on the device of the latest fused call (not a buffer: checkpoints keep their layout).
  mutable at::Tensor device_parents_;
};
TORCH_MODULE(KinematicTree);

// Posed vertices sum_j w_ij A_j [v_i; 1] of rest vertices (B, V, 3) with weights (V, J), dense or sparse COO (each
// vertex follows a few joints: the sparse product costs a few multiply-adds per vertex instead of J), and
// transforms (B, J, 4, 4). Differentiable with respect to the vertices and the transforms.
at::Tensor linear_blend_skinning(const at::Tensor& rest_vertices, const at::Tensor& weights,
                                 const at::Tensor& skinning_transforms);

// Dense (V, J) skinning weights as the sparse COO matrix linear_blend_skinning multiplies fastest with.
at::Tensor sparse_skinning_weights(const at::Tensor& weights);

// The SMPL pose-corrective feature: R_j - I of every non-root joint, (B, J, 3, 3) -> (B, 9 (J - 1)).
at::Tensor pose_feature(const at::Tensor& rotations);

}  // namespace sfgs::body
