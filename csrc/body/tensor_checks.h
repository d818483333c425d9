#pragma once
// How the body-model code checks tensors at its public boundaries, names them in error messages ("a Float tensor
// of shape [2, 3] on cpu") and copies them into module buffers.
#include <string>

#include <ATen/core/Tensor.h>

#include "common/tensor_description.h"

namespace sfgs::body {

// Checks `t` is defined with exactly this shape, dtype and device; `what` names it ("Smplx: betas").
inline void check_tensor(const at::Tensor& t, const std::string& what, at::IntArrayRef shape, at::ScalarType dtype,
                         c10::Device device) {
  TORCH_CHECK(t.defined() && t.sizes() == shape && t.scalar_type() == dtype && t.device() == device, what,
              " must be a ", dtype, " tensor of shape ", shape, " on ", device, ", got ", describe(t));
}

// A module buffer made from `t`: always a new tensor. Module::to() converts buffers in place (set_data), so a
// buffer that shared its tensor with the caller's model data would drag that data, and every other module built
// from it, along to the new device or dtype.
inline at::Tensor buffer_copy(const at::Tensor& t, at::ScalarType dtype) {
  return t.to(dtype, /*non_blocking=*/false, /*copy=*/true).contiguous();
}

}  // namespace sfgs::body
