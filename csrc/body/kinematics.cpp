#include "body/kinematics.h"

#include <string>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/body_backend.h"
#include "body/tensor_checks.h"

namespace sfgs::body {
namespace {

// [R | t] (..., 3, 3) and (..., 3) -> (..., 4, 4) with the last row (0, 0, 0, 1).
at::Tensor homogeneous(const at::Tensor& rotation, const at::Tensor& translation) {
  const at::Tensor top = at::cat({rotation, translation.unsqueeze(-1)}, -1);
  at::Tensor bottom = at::zeros_like(top.narrow(-2, 0, 1));
  bottom.select(-1, 3).fill_(1);
  return at::cat({top, bottom}, -2);
}

// Casts the floating-point parameters and buffers of `module` (not its children) to `dtype` and moves them all
// to `device`.
void convert_own_tensors(torch::nn::Module& module, const c10::optional<torch::Device>& device, torch::Dtype dtype,
                         bool non_blocking) {
  const auto convert = [&](at::Tensor& t) {
    const at::ScalarType target = at::isFloatingType(t.scalar_type()) ? dtype : t.scalar_type();
    t.set_data(t.to(device.value_or(t.device()), target, non_blocking));
  };
  for (auto& parameter : module.named_parameters(/*recurse=*/false)) convert(parameter.value());
  for (auto& buffer : module.named_buffers(/*recurse=*/false)) convert(buffer.value());
}

}  // namespace

void BodyModule::to(torch::Device device, torch::Dtype dtype, bool non_blocking) {
  for (const auto& child : children()) child->to(device, dtype, non_blocking);
  convert_own_tensors(*this, device, dtype, non_blocking);
}

void BodyModule::to(torch::Dtype dtype, bool non_blocking) {
  for (const auto& child : children()) child->to(dtype, non_blocking);
  convert_own_tensors(*this, c10::nullopt, dtype, non_blocking);
}

KinematicTreeImpl::KinematicTreeImpl(std::vector<int64_t> parents) : parents_(std::move(parents)) {
  TORCH_CHECK(!parents_.empty() && parents_[0] == -1, "KinematicTree: joint 0 must be the root (parent -1)");
  std::vector<int64_t> depth(parents_.size(), 0);
  int64_t deepest = 0;
  for (size_t j = 1; j < parents_.size(); ++j) {
    TORCH_CHECK(parents_[j] >= 0 && parents_[j] < static_cast<int64_t>(j), "KinematicTree: the parent of joint ", j,
                " must be an earlier joint, got ", parents_[j]);
    depth[j] = depth[parents_[j]] + 1;
    deepest = std::max(deepest, depth[j]);
  }
  std::vector<int64_t> order, slot(parents_.size());
  for (int64_t d = 0; d <= deepest; ++d) {
    std::vector<int64_t> joints, parent_slots;
    for (size_t j = 0; j < parents_.size(); ++j) {
      if (depth[j] != d) continue;
      joints.push_back(static_cast<int64_t>(j));
      if (d > 0) parent_slots.push_back(slot[parents_[j]]);
    }
    for (int64_t j : joints) {
      slot[j] = static_cast<int64_t>(order.size());
      order.push_back(j);
    }
    if (d == 0) continue;
    const std::string level = std::to_string(d);
    level_joints_.push_back(register_buffer("level" + level + "_joints", at::tensor(joints, at::kLong)));
    level_parent_slots_.push_back(
        register_buffer("level" + level + "_parent_slots", at::tensor(parent_slots, at::kLong)));
  }
  root_ = register_buffer("root", at::zeros({1}, at::kLong));
  std::vector<int64_t> parent_or_self(parents_);
  parent_or_self[0] = 0;
  parent_or_self_ = register_buffer("parent_or_self", at::tensor(parent_or_self, at::kLong));
  depth_order_inverse_ = register_buffer("depth_order_inverse", at::tensor(slot, at::kLong));
}

bool KinematicTreeImpl::in_subtree(int64_t ancestor, int64_t joint) const {
  TORCH_CHECK(ancestor >= 0 && ancestor < size() && joint >= 0 && joint < size(), "KinematicTree::in_subtree: joints ",
              ancestor, " and ", joint, " must lie in [0, ", size(), ")");
  for (int64_t j = joint; j >= 0; j = parents_[j])
    if (j == ancestor) return true;
  return false;
}

void KinematicTreeImpl::check_pose_inputs(const at::Tensor& rotations, const at::Tensor& rest_joints,
                                          const at::Tensor& translation) const {
  const int64_t j = size();
  TORCH_CHECK(rotations.dim() == 4 && rotations.size(1) == j && rotations.size(2) == 3 && rotations.size(3) == 3,
              "KinematicTree::pose: rotations must have shape (B, ", j, ", 3, 3), got ", describe(rotations));
  const int64_t b = rotations.size(0);
  TORCH_CHECK(
      rest_joints.dim() == 3 && rest_joints.size(0) == b && rest_joints.size(1) == j && rest_joints.size(2) == 3,
      "KinematicTree::pose: rest_joints must have shape (", b, ", ", j, ", 3), got ", describe(rest_joints));
  TORCH_CHECK(translation.dim() == 2 && translation.size(0) == b && translation.size(1) == 3,
              "KinematicTree::pose: translation must have shape (", b, ", 3), got ", describe(translation));
}

PosedSkeleton KinematicTreeImpl::pose(const at::Tensor& rotations, const at::Tensor& rest_joints,
                                      const at::Tensor& translation) const {
  check_pose_inputs(rotations, rest_joints, translation);
  return fuses(rotations, rest_joints, translation) ? pose_fused(rotations, rest_joints, translation)
                                                    : compose(rotations, rest_joints, translation);
}

bool KinematicTreeImpl::fuses(const at::Tensor& rotations, const at::Tensor& rest_joints,
                              const at::Tensor& translation) const {
  for (const at::Tensor* t : {&rotations, &rest_joints, &translation})
    if (!t->is_cuda() || t->scalar_type() != at::kFloat || t->requires_grad() || t->device() != rotations.device())
      return false;
  return cuda::available();
}

PosedSkeleton KinematicTreeImpl::pose_fused(const at::Tensor& rotations, const at::Tensor& rest_joints,
                                            const at::Tensor& translation) const {
  const int64_t b = rotations.size(0), j = size();
  if (!device_parents_.defined() || device_parents_.device() != rotations.device())
    device_parents_ =
        at::tensor(std::vector<int32_t>(parents_.begin(), parents_.end()), at::kInt).to(rotations.device());
  const at::Tensor r = rotations.contiguous(), rest = rest_joints.contiguous(), t = translation.contiguous();
  PosedSkeleton out;
  out.joints = at::empty({b, j, 3}, r.options());
  out.joint_transforms = at::empty({b, j, 4, 4}, r.options());
  out.skinning_transforms = at::empty({b, j, 4, 4}, r.options());
  KinematicChainArrays arrays{};
  arrays.rotations = r.data_ptr<float>();
  arrays.rest_joints = rest.data_ptr<float>();
  arrays.translation = t.data_ptr<float>();
  arrays.parents = device_parents_.data_ptr<int32_t>();
  arrays.batch = b;
  arrays.joints = static_cast<int32_t>(j);
  arrays.posed_joints = out.joints.data_ptr<float>();
  arrays.joint_transforms = out.joint_transforms.data_ptr<float>();
  arrays.skinning_transforms = out.skinning_transforms.data_ptr<float>();
  cuda::kinematic_chain(arrays, r.device());
  return out;
}

PosedSkeleton KinematicTreeImpl::pose_reference(const at::Tensor& rotations, const at::Tensor& rest_joints,
                                                const at::Tensor& translation) const {
  check_pose_inputs(rotations, rest_joints, translation);
  return compose(rotations, rest_joints, translation);
}

PosedSkeleton KinematicTreeImpl::compose(const at::Tensor& rotations, const at::Tensor& rest_joints,
                                         const at::Tensor& translation) const {
  const int64_t j = size();
  // Offsets of every joint from its parent in the rest pose; the root's is its position plus the translation.
  at::Tensor offsets = rest_joints - rest_joints.index_select(1, parent_or_self_);
  offsets = at::cat({rest_joints.narrow(1, 0, 1) + translation.unsqueeze(1), offsets.narrow(1, 1, j - 1)}, 1);

  at::Tensor world_rotation = rotations.index_select(1, root_);
  at::Tensor world_position = offsets.index_select(1, root_);
  for (size_t level = 0; level < level_joints_.size(); ++level) {
    const at::Tensor parent_rotation = world_rotation.index_select(1, level_parent_slots_[level]);
    const at::Tensor parent_position = world_position.index_select(1, level_parent_slots_[level]);
    const at::Tensor local_rotation = rotations.index_select(1, level_joints_[level]);
    const at::Tensor local_offset = offsets.index_select(1, level_joints_[level]);
    world_rotation = at::cat({world_rotation, parent_rotation.matmul(local_rotation)}, 1);
    world_position =
        at::cat({world_position, parent_position + parent_rotation.matmul(local_offset.unsqueeze(-1)).squeeze(-1)}, 1);
  }
  world_rotation = world_rotation.index_select(1, depth_order_inverse_);
  world_position = world_position.index_select(1, depth_order_inverse_);

  PosedSkeleton result;
  result.joints = world_position;
  result.joint_transforms = homogeneous(world_rotation, world_position);
  result.skinning_transforms =
      homogeneous(world_rotation, world_position - world_rotation.matmul(rest_joints.unsqueeze(-1)).squeeze(-1));
  return result;
}

at::Tensor linear_blend_skinning(const at::Tensor& rest_vertices, const at::Tensor& weights,
                                 const at::Tensor& skinning_transforms) {
  TORCH_CHECK(weights.dim() == 2, "linear_blend_skinning: weights must have shape (V, J), got ", describe(weights));
  const int64_t v = weights.size(0), j = weights.size(1);
  TORCH_CHECK(skinning_transforms.dim() == 4 && skinning_transforms.size(1) == j && skinning_transforms.size(2) == 4 &&
                  skinning_transforms.size(3) == 4,
              "linear_blend_skinning: transforms must have shape (B, ", j, ", 4, 4), got ",
              describe(skinning_transforms));
  const int64_t b = skinning_transforms.size(0);
  TORCH_CHECK(rest_vertices.dim() == 3 && rest_vertices.size(0) == b && rest_vertices.size(1) == v &&
                  rest_vertices.size(2) == 3,
              "linear_blend_skinning: rest_vertices must have shape (", b, ", ", v, ", 3), got ",
              describe(rest_vertices));
  // The top 3 x 4 of every transform blended per vertex, all batch elements in one (V, J) x (J, 12 B) product (a
  // broadcast (V, J) x (B, J, 12) matmul would first copy the weights B times).
  const at::Tensor per_joint =
      skinning_transforms.narrow(2, 0, 3).reshape({b, j, 12}).transpose(0, 1).reshape({j, b * 12});
  const at::Tensor blended = at::mm(weights, per_joint).view({v, b, 3, 4});
  // Applied by multiply-adds on strided views: reducing over a size-3 axis is several times slower.
  const at::Tensor p = rest_vertices.transpose(0, 1).unsqueeze(-1);  // (V, B, 3, 1)
  at::Tensor posed = blended.select(3, 3);
  for (int64_t c = 0; c < 3; ++c) posed = posed + blended.select(3, c) * p.select(2, c);
  return posed.transpose(0, 1).contiguous();
}

at::Tensor sparse_skinning_weights(const at::Tensor& weights) {
  TORCH_CHECK(weights.dim() == 2 && at::isFloatingType(weights.scalar_type()) && !weights.is_sparse(),
              "sparse_skinning_weights: weights must be a dense floating (V, J) tensor, got ", describe(weights));
  // nonzero() and masked_select() both walk the weights in row-major order, so indices and values pair up.
  const at::Tensor used = weights != 0;
  return at::sparse_coo_tensor(used.nonzero().t(), weights.masked_select(used), weights.sizes()).coalesce();
}

at::Tensor pose_feature(const at::Tensor& rotations) {
  TORCH_CHECK(rotations.dim() == 4 && rotations.size(1) >= 1 && rotations.size(2) == 3 && rotations.size(3) == 3,
              "pose_feature: rotations must have shape (B, J, 3, 3), got ", describe(rotations));
  const at::Tensor eye = at::eye(3, rotations.options());
  return (rotations.narrow(1, 1, rotations.size(1) - 1) - eye).flatten(1);
}

}  // namespace sfgs::body
