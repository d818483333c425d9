#pragma once
// A reader for the safetensors format (huggingface/safetensors): u64 little-endian header length N, N bytes of
// JSON {"name": {"dtype", "shape", "data_offsets": [begin, end)}, "__metadata__": {string: string}}, then the
// raw little-endian row-major data. Every malformed or inconsistent file is an error naming the file.
#include <map>
#include <string>

#include <ATen/core/Tensor.h>

namespace sfgs {

struct SafetensorsContent {
  std::map<std::string, at::Tensor> tensors;    // CPU tensors, owned (copied out of the file)
  std::map<std::string, std::string> metadata;  // the optional "__metadata__" map
};

// Supported dtypes: F64, F32, F16, BF16, I64, I32, I16, I8, U8, BOOL.
SafetensorsContent read_safetensors(const std::string& path);

}  // namespace sfgs
