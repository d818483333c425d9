#pragma once
// Rotation parameterisations shared by the whole project: axis-angle (SMPL-X poses), 3x3 matrices and the 6D
// representation (the first two rows of the matrix, PyTorch3D's matrix_to_rotation_6d convention, as SFGS uses
// for its joint features). All functions are batched over leading dimensions, work on any device and floating
// dtype, and are differentiable everywhere, including at the zero rotation.
#include <ATen/core/Tensor.h>

namespace sfgs::body {

// (..., 3) axis-angle (axis times angle in radians, right-handed) -> (..., 3, 3) rotation matrices. float32 on a
// CUDA device without a gradient: one fused kernel (csrc/cuda/rotations.cu); otherwise, and as its reference,
// axis_angle_to_matrix_reference, the LibTorch composition.
at::Tensor axis_angle_to_matrix(const at::Tensor& axis_angle);
at::Tensor axis_angle_to_matrix_reference(const at::Tensor& axis_angle);

// (..., 3, 3) rotation matrices -> (..., 3) axis-angle with the angle in [0, pi].
at::Tensor matrix_to_axis_angle(const at::Tensor& matrix);

// (..., 3, 3) rotation matrices -> (..., 4) unit quaternions (w, x, y, z) with w >= 0, well conditioned for every
// rotation (180 degrees included).
at::Tensor matrix_to_quaternion(const at::Tensor& matrix);

// (..., 3, 3) -> (..., 6): the first two rows, concatenated.
at::Tensor matrix_to_rotation_6d(const at::Tensor& matrix);

// (..., 6) -> (..., 3, 3): Gram-Schmidt on the two rows; the third row is their cross product.
at::Tensor rotation_6d_to_matrix(const at::Tensor& rotation_6d);

}  // namespace sfgs::body
