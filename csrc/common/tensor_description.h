#pragma once
// How every error message of sfgs names a tensor it did not expect.
#include <string>

#include <ATen/core/Tensor.h>

namespace sfgs {

// "a Float tensor of shape [2, 3] on cpu", or "an undefined tensor".
std::string describe(const at::Tensor& t);

// Checks `t` is defined with exactly this shape, dtype and device; `what` names it ("Smplx: betas").
void check_tensor(const at::Tensor& t, const std::string& what, at::IntArrayRef shape, at::ScalarType dtype,
                  c10::Device device);

// float or double: the dtypes the fused ops' CPU backends and CUDA kernels are written for.
bool is_float_or_double(const at::Tensor& t);

// Whether every value of an integer tensor lies in [low, high) (true when it is empty). Reads the tensor on the host:
// for checks at a boundary, not inside a recorded pass.
bool values_within(const at::Tensor& t, int64_t low, int64_t high);

}  // namespace sfgs
