#include "common/tensor_description.h"

#include <sstream>

namespace sfgs {

std::string describe(const at::Tensor& t) {
  if (!t.defined()) return "an undefined tensor";
  std::ostringstream s;
  s << "a " << t.scalar_type() << " tensor of shape " << t.sizes() << " on " << t.device();
  return s.str();
}

void check_tensor(const at::Tensor& t, const std::string& what, at::IntArrayRef shape, at::ScalarType dtype,
                  c10::Device device) {
  TORCH_CHECK(t.defined() && t.sizes() == shape && t.scalar_type() == dtype && t.device() == device, what,
              " must be a ", dtype, " tensor of shape ", shape, " on ", device, ", got ", describe(t));
}

bool is_float_or_double(const at::Tensor& t) { return t.scalar_type() == at::kFloat || t.scalar_type() == at::kDouble; }

bool values_within(const at::Tensor& t, int64_t low, int64_t high) {
  return t.numel() == 0 || (t.min().item<int64_t>() >= low && t.max().item<int64_t>() < high);
}

}  // namespace sfgs
