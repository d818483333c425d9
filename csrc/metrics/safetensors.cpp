// The safetensors reader. The whole file is read at once: the LPIPS files it serves are a few MB.
#include "metrics/safetensors.h"

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

namespace sfgs {
namespace {

static_assert(__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__, "safetensors data is little-endian; so must the host be");

// The format's own limit on the JSON header, which also rejects garbage lengths before allocating.
constexpr uint64_t kMaxHeaderBytes = 100u << 20;

at::ScalarType scalar_type_of(const std::string& dtype, const std::string& path, const std::string& name) {
  static const std::map<std::string, at::ScalarType> types = {
      {"F64", at::kDouble}, {"F32", at::kFloat}, {"F16", at::kHalf}, {"BF16", at::kBFloat16}, {"I64", at::kLong},
      {"I32", at::kInt},    {"I16", at::kShort}, {"I8", at::kChar},  {"U8", at::kByte},       {"BOOL", at::kBool}};
  const auto it = types.find(dtype);
  TORCH_CHECK(it != types.end(), "safetensors file '", path, "': tensor '", name, "' has unsupported dtype '", dtype,
              "' (supported: F64, F32, F16, BF16, I64, I32, I16, I8, U8, BOOL)");
  return it->second;
}

struct TensorEntry {
  std::string name;
  at::ScalarType type;
  std::vector<int64_t> shape;
  uint64_t begin, end;
};

TensorEntry parse_entry(const std::string& path, const std::string& name, const nlohmann::json& entry) {
  const auto fail_prefix = "safetensors file '" + path + "': tensor '" + name + "' ";
  TORCH_CHECK(entry.is_object() && entry.contains("dtype") && entry.contains("shape") && entry.contains("data_offsets"),
              fail_prefix, "must be an object with dtype, shape and data_offsets, got ", entry.dump());
  TORCH_CHECK(entry["dtype"].is_string(), fail_prefix, "has a non-string dtype ", entry["dtype"].dump());
  TensorEntry t;
  t.name = name;
  t.type = scalar_type_of(entry["dtype"].get<std::string>(), path, name);
  const auto& shape = entry["shape"];
  TORCH_CHECK(shape.is_array(), fail_prefix, "has a shape that is not a list: ", shape.dump());
  uint64_t numel = 1;
  for (const auto& dim : shape) {
    TORCH_CHECK(dim.is_number_unsigned(), fail_prefix, "has an invalid shape ", shape.dump());
    const uint64_t size = dim.get<uint64_t>();
    TORCH_CHECK(size == 0 || numel <= (uint64_t(1) << 62) / size, fail_prefix, "has an overflowing shape ",
                shape.dump());
    numel *= size;
    t.shape.push_back(int64_t(size));
  }
  const auto& offsets = entry["data_offsets"];
  TORCH_CHECK(
      offsets.is_array() && offsets.size() == 2 && offsets[0].is_number_unsigned() && offsets[1].is_number_unsigned(),
      fail_prefix, "has data_offsets that are not two non-negative integers: ", offsets.dump());
  t.begin = offsets[0].get<uint64_t>();
  t.end = offsets[1].get<uint64_t>();
  const uint64_t bytes = numel * at::elementSize(t.type);
  TORCH_CHECK(t.begin <= t.end && t.end - t.begin == bytes, fail_prefix, "has data_offsets [", t.begin, ", ", t.end,
              ") that do not hold its ", bytes, " bytes (shape ", shape.dump(), ", dtype ",
              entry["dtype"].get<std::string>(), ")");
  return t;
}

}  // namespace

SafetensorsContent read_safetensors(const std::string& path) {
  TORCH_CHECK(std::filesystem::is_regular_file(path), "safetensors file '", path, "' does not exist");
  std::ifstream file(path, std::ios::binary);
  TORCH_CHECK(file, "safetensors file '", path, "' cannot be opened");
  const std::vector<char> bytes((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  TORCH_CHECK(!file.bad(), "safetensors file '", path, "' could not be read");
  TORCH_CHECK(bytes.size() >= 8, "safetensors file '", path, "' is truncated: ", bytes.size(),
              " bytes, fewer than the 8-byte header length");
  uint64_t header_bytes = 0;
  for (int i = 7; i >= 0; --i) header_bytes = (header_bytes << 8) | uint8_t(bytes[i]);
  TORCH_CHECK(header_bytes <= kMaxHeaderBytes && header_bytes <= bytes.size() - 8, "safetensors file '", path,
              "' is corrupt: header length ", header_bytes, " does not fit in the file's ", bytes.size(), " bytes");

  nlohmann::json header;
  try {
    header = nlohmann::json::parse(bytes.begin() + 8, bytes.begin() + 8 + int64_t(header_bytes));
  } catch (const nlohmann::json::exception& e) {
    TORCH_CHECK(false, "safetensors file '", path, "' is corrupt: its header is not valid JSON (", e.what(), ")");
  }
  TORCH_CHECK(header.is_object(), "safetensors file '", path, "' is corrupt: its header is not a JSON object");

  SafetensorsContent content;
  std::vector<TensorEntry> entries;
  for (const auto& [name, value] : header.items()) {
    if (name == "__metadata__") {
      TORCH_CHECK(value.is_object(), "safetensors file '", path, "': __metadata__ must be an object");
      for (const auto& [key, text] : value.items()) {
        TORCH_CHECK(text.is_string(), "safetensors file '", path, "': __metadata__ value of '", key,
                    "' must be a string, got ", text.dump());
        content.metadata[key] = text.get<std::string>();
      }
      continue;
    }
    entries.push_back(parse_entry(path, name, value));
  }

  const char* data = bytes.data() + 8 + header_bytes;
  const uint64_t data_bytes = bytes.size() - 8 - header_bytes;
  std::sort(entries.begin(), entries.end(), [](const auto& a, const auto& b) { return a.begin < b.begin; });
  uint64_t previous_end = 0;
  for (const TensorEntry& t : entries) {
    TORCH_CHECK(t.end <= data_bytes, "safetensors file '", path, "' is truncated: tensor '", t.name,
                "' ends at data byte ", t.end, " but the file holds ", data_bytes, " data bytes");
    TORCH_CHECK(t.begin >= previous_end, "safetensors file '", path, "' is corrupt: tensor '", t.name,
                "' overlaps the tensor before it");
    previous_end = t.end;
    at::Tensor tensor = at::empty(t.shape, at::TensorOptions().dtype(t.type));
    if (t.end > t.begin) std::memcpy(tensor.data_ptr(), data + t.begin, t.end - t.begin);
    content.tensors.emplace(t.name, std::move(tensor));
  }
  return content;
}

}  // namespace sfgs
