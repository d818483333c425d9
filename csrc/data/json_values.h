#pragma once
// Numbers from JSON documents of datasets (flat or nested arrays) as tensors, with errors naming the document.
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>
#include <nlohmann/json_fwd.hpp>

namespace sfgs::data {

// All numbers of `value` (a number or arbitrarily nested arrays of numbers) in order, as a float32 tensor of
// `shape` ({-1}: any length). `where` names the document and key in errors.
at::Tensor json_numbers(const nlohmann::json& value, const std::vector<int64_t>& shape, const std::string& where);

// Parses a JSON file; errors name the file.
nlohmann::json read_json_file(const std::string& path);

}  // namespace sfgs::data
