#include "common/tensor_description.h"

#include <sstream>

namespace sfgs {

std::string describe(const at::Tensor& t) {
  if (!t.defined()) return "an undefined tensor";
  std::ostringstream s;
  s << "a " << t.scalar_type() << " tensor of shape " << t.sizes() << " on " << t.device();
  return s.str();
}

bool is_float_or_double(const at::Tensor& t) { return t.scalar_type() == at::kFloat || t.scalar_type() == at::kDouble; }

}  // namespace sfgs
