#include "data/json_values.h"

#include <fstream>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

namespace sfgs::data {
namespace {

void collect(const nlohmann::json& v, std::vector<float>& out, const std::string& where) {
  if (v.is_number()) {
    out.push_back(v.get<float>());
    return;
  }
  TORCH_CHECK(v.is_array(), where, ": expected numbers or arrays of numbers, got ", v.dump());
  for (const nlohmann::json& item : v) collect(item, out, where);
}

}  // namespace

at::Tensor json_numbers(const nlohmann::json& value, const std::vector<int64_t>& shape, const std::string& where) {
  std::vector<float> values;
  collect(value, values, where);
  const at::Tensor flat = at::tensor(values, at::kFloat);
  if (shape.size() == 1 && shape[0] == -1) return flat;
  int64_t expected = 1;
  for (int64_t s : shape) expected *= s;
  TORCH_CHECK(int64_t(values.size()) == expected, where, ": expected ", expected, " numbers, got ", values.size());
  return flat.view(shape);
}

nlohmann::json read_json_file(const std::string& path) {
  std::ifstream in(path);
  TORCH_CHECK(in.good(), "cannot open '", path, "'");
  try {
    return nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    TORCH_CHECK(false, "'", path, "' is not valid JSON: ", e.what());
  }
}

}  // namespace sfgs::data
