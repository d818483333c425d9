#pragma once
// What torch.library.opcheck checks of an sfgs dispatcher op (ops/registration.h), for a LibTorch that lacks it (the
// pytest suite runs opcheck itself where torch has it): the op is registered with a CPU, a Meta and, where asked, an
// Autograd kernel (its alias key), and a CUDA one in a CUDA build; called through the dispatcher on CPU tensors it
// returns what the Meta kernel describes from the same arguments on the meta device (shapes, dtypes, strides).
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/core/dispatch/Dispatcher.h>
#include <gtest/gtest.h>

#include "ops/registration.h"

namespace sfgs::testing {

inline c10::OperatorHandle registered_op(const std::string& qualified_name) {
  return c10::Dispatcher::singleton().findSchemaOrThrow(qualified_name.c_str(), "");
}

inline void expect_backend_kernels(const std::string& qualified_name, bool differentiable) {
  const c10::OperatorHandle op = registered_op(qualified_name);
  EXPECT_TRUE(op.hasKernelForDispatchKey(c10::DispatchKey::CPU)) << qualified_name;
  EXPECT_TRUE(op.hasKernelForDispatchKey(c10::DispatchKey::Meta)) << qualified_name;
  EXPECT_EQ(op.hasKernelForDispatchKey(c10::DispatchKey::CUDA), ops::kBuiltWithCuda) << qualified_name;
  if (differentiable) EXPECT_TRUE(op.hasKernelForDispatchKey(c10::DispatchKey::Autograd)) << qualified_name;
}

// `arguments` in the schema's order; tensors among them on the CPU.
inline std::vector<c10::IValue> call_boxed(const c10::OperatorHandle& op, std::vector<c10::IValue> arguments) {
  op.callBoxed(&arguments);
  return arguments;
}

inline c10::IValue on_meta(const c10::IValue& v) {
  if (v.isTensor()) return c10::IValue(v.toTensor().to(at::kMeta));
  if (!v.isTensorList()) return v;
  std::vector<at::Tensor> list;
  for (const at::Tensor& t : v.toTensorVector()) list.push_back(t.to(at::kMeta));
  return c10::IValue(list);
}

inline void expect_meta_describes_cpu(const std::string& qualified_name, const std::vector<c10::IValue>& arguments) {
  const c10::OperatorHandle op = registered_op(qualified_name);
  const std::vector<c10::IValue> cpu = call_boxed(op, arguments);
  std::vector<c10::IValue> meta_arguments;
  for (const c10::IValue& v : arguments) meta_arguments.push_back(on_meta(v));
  // Below autograd: LibTorch 1.13 has no autograd fallthrough for meta tensors, and a backward op has no node.
  const at::AutoDispatchBelowADInplaceOrView below_autograd;
  const std::vector<c10::IValue> meta = call_boxed(op, meta_arguments);
  ASSERT_EQ(cpu.size(), meta.size()) << qualified_name;
  for (size_t k = 0; k < cpu.size(); ++k) {
    ASSERT_TRUE(cpu[k].isTensor() && meta[k].isTensor()) << qualified_name << " output " << k;
    const at::Tensor c = cpu[k].toTensor(), m = meta[k].toTensor();
    EXPECT_TRUE(m.is_meta()) << qualified_name << " output " << k;
    EXPECT_EQ(c.sizes(), m.sizes()) << qualified_name << " output " << k;
    EXPECT_EQ(c.scalar_type(), m.scalar_type()) << qualified_name << " output " << k;
    EXPECT_EQ(c.strides(), m.strides()) << qualified_name << " output " << k;
  }
}

}  // namespace sfgs::testing
