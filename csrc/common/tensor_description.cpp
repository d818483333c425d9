#include "common/tensor_description.h"

#include <sstream>

namespace sfgs {

std::string describe(const at::Tensor& t) {
  if (!t.defined()) return "an undefined tensor";
  std::ostringstream s;
  s << "a " << t.scalar_type() << " tensor of shape " << t.sizes() << " on " << t.device();
  return s.str();
}

}  // namespace sfgs
