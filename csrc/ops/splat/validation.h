#pragma once
// Checks of the splatting op's arguments. Every message starts with "sfgs::render" and says what was expected and
// what came (docs/splatting.md lists which inputs are errors and which are culled).
#include <cstdint>
#include <string>

#include <ATen/core/Tensor.h>

#include "common/tensor_description.h"
#include "ops/splat/backend.h"
#include "ops/splat/splat.h"

namespace sfgs::splat {

// Shapes, dtypes, devices and the parameterisation: everything a tensor's metadata tells. Returns the inputs
// contiguous, with opacities as (N). on_backend_device: the tensors must also be on the CPU or a CUDA device this
// build supports (the Meta kernel, which only describes outputs, passes false).
SplatInputs validated_inputs(const SplatInputs& given, bool on_backend_device);

// The tensors are on a device the backends run on: the CPU, or CUDA in a build with the CUDA backend.
void check_backend_device(const at::Tensor& means);

// camera_problem() as an error.
void check_camera(const Camera& camera);

// Value checks that read the data (host tensors only; CUDA folds the opacity check into its forward pass).
void check_background_finite(const at::Tensor& background);
void check_opacities(const at::Tensor& opacities);  // contiguous (N)

// The error text for opacities outside [0, 1] or not finite, shared by both backends.
std::string opacity_problem(int64_t invalid, int64_t count, int64_t first_index, double first_value);

}  // namespace sfgs::splat
