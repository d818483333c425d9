#pragma once
// How every sfgs op meets the dispatcher (docs/architecture.md, "Ops"): its schemas in the `sfgs` library
// (TORCH_LIBRARY_FRAGMENT; the library itself is defined once, in ops/splat/op.cpp), a kernel for each backend the
// build has (CPU always; CUDA only in a build with the CUDA backend, so a build without one needs no stand-ins), a Meta
// kernel that describes the outputs from the arguments alone, and an Autograd kernel, the op's one autograd node, which
// redispatches below autograd for the forward pass and calls the op's backward op for the gradients. Each op's public
// function calls its op through the dispatcher, as torch.ops.sfgs.<op> does; referencing it keeps the op's file, and
// with it the registration, in a static link.
#include <ATen/core/Tensor.h>
#include <ATen/core/dispatch/Dispatcher.h>
#include <c10/util/Optional.h>

namespace sfgs::ops {

// Whether this build has the CUDA backend (CMake's SFGS_WITH_CUDA).
#if defined(SFGS_WITH_CUDA)
inline constexpr bool kBuiltWithCuda = true;
#else
inline constexpr bool kBuiltWithCuda = false;
#endif

// A schema's `Tensor?` argument; an undefined tensor is passed as None.
using OptionalTensor = c10::optional<at::Tensor>;
inline OptionalTensor optional_tensor(const at::Tensor& t) { return t.defined() ? OptionalTensor(t) : c10::nullopt; }

// The typed handle of the registered op `qualified_name` ("sfgs::<op>").
template <typename Signature> c10::TypedOperatorHandle<Signature> find_op(const char* qualified_name) {
  return c10::Dispatcher::singleton().findSchemaOrThrow(qualified_name, "").typed<Signature>();
}

}  // namespace sfgs::ops
