#include "common/matmul_precision.h"

#include <ATen/Context.h>
#include <c10/util/Exception.h>

namespace sfgs {

Tf32MatmulScope::Tf32MatmulScope(bool allow) {
  at::Context& context = at::globalContext();
  try {
    previous_ = context.allowTF32CuBLAS();
  } catch (const c10::Error&) {
    return;  // the process mixed LibTorch's two settings: not ours to change
  }
  if (previous_ == allow) return;
  context.setAllowTF32CuBLAS(allow);
  changed_ = true;
}

Tf32MatmulScope::~Tf32MatmulScope() {
  if (changed_) at::globalContext().setAllowTF32CuBLAS(previous_);
}

}  // namespace sfgs
