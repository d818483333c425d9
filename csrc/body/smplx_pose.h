#pragma once
// The one SMPL-X pose type of sfgs, by the SMPL-X reference's names (vchoutas/smplx): datasets store it per frame,
// the avatar is driven by it, the SMPL-X layer takes a batch of it, the CLI and Python pass it on. Conversions
// happen only at file boundaries (dataset, NeuMan and X-Humans readers, motion files).
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

namespace sfgs::body {

// Axis-angle rotations. One frame has no leading dimension; a batch has a leading dimension B on every field. An
// undefined field means zeros (at rest).
struct SmplxPose {
  at::Tensor global_orient;    // (3): the pelvis
  at::Tensor body_pose;        // (21, 3): joints 1..21 ((63) accepted)
  at::Tensor jaw_pose;         // (3)
  at::Tensor leye_pose;        // (3)
  at::Tensor reye_pose;        // (3)
  at::Tensor left_hand_pose;   // (15, 3) full axis-angle ((45) accepted; PCA coefficients for a PCA layer)
  at::Tensor right_hand_pose;  // (15, 3)
  at::Tensor expression;       // (E), any E (padded or truncated by whoever uses it)
  at::Tensor transl;           // (3)

  struct Field {
    const char* name;
    at::Tensor SmplxPose::*member;
    int64_t joints;  // axis-angle joints it holds (3 values each); 0 for the expression (any length)
  };
  static const std::array<Field, 9>& fields();

  // One frame at rest with `expression_count` expression coefficients, float32 on the CPU.
  static SmplxPose zeros(int64_t expression_count);
  // One-frame poses as one batch (every field defined in every frame, or in none).
  static SmplxPose stack(const std::vector<SmplxPose>& frames);
  // Frame `index` of a batch (every defined field's entry `index` along the leading dimension).
  SmplxPose frame(int64_t index) const;
  // Every defined field converted (dtype, device).
  SmplxPose to(const at::TensorOptions& options) const;
  // "numel,numel,...": which fields the pose gives and their sizes (-1: not given). Poses of one layout pack alike.
  std::string layout() const;
  // Every defined field's values, flattened in fields() order, as one float32 vector on the CPU: one upload.
  at::Tensor packed() const;
  // A pose of this one's layout whose fields are views of `buffer` (as packed() lays the values out): a device copy
  // that one upload of packed() fills.
  SmplxPose views_of(const at::Tensor& buffer) const;
  // The first field holding NaN or Inf, as "body_pose must be finite, got nan at index 13 (1 of 63 values are not
  // finite)"; empty when every value is finite. Fields on the CPU are checked where they lie, device ones in one
  // reduction (a single synchronisation).
  std::string non_finite() const;
};

}  // namespace sfgs::body
