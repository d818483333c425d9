#pragma once
// How the body-model code checks tensors at its public boundaries (check_tensor, common/tensor_description.h), names
// them in error messages ("a Float tensor of shape [2, 3] on cpu") and copies them into module buffers.
#include <string>

#include <ATen/core/Tensor.h>

#include "common/tensor_description.h"

namespace sfgs::body {

// A module buffer made from `t`: always a new tensor. Module::to() converts buffers in place (set_data), so a
// buffer that shared its tensor with the caller's model data would drag that data, and every other module built
// from it, along to the new device or dtype.
inline at::Tensor buffer_copy(const at::Tensor& t, at::ScalarType dtype) {
  return t.to(dtype, /*non_blocking=*/false, /*copy=*/true).contiguous();
}

}  // namespace sfgs::body
