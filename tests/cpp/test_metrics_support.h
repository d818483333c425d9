#pragma once
// Helpers shared by the metric suites: where ../shared is, random LPIPS weights (tests that need no files),
// a minimal safetensors writer for building valid and corrupt files, and error-message checks.
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "test_files.h"
#include <nlohmann/json.hpp>

#include "metrics/lpips.h"

namespace sfgs::testing {

// A uniform random (h, w, 3) image in [0, 1) of `dtype`, the same for the same seed.
inline at::Tensor random_image(int64_t h, int64_t w, uint64_t seed, at::ScalarType dtype = at::kDouble) {
  at::manual_seed(seed);
  return at::rand({h, w, 3}, dtype);
}

// $SFGS_SHARED_DIR, else <repository root>/../shared (the root found from this file's path).
inline std::string shared_dir() {
  if (const char* dir = std::getenv("SFGS_SHARED_DIR"); dir && *dir) return dir;
  const std::filesystem::path repository = std::filesystem::path(__FILE__).parent_path().parent_path().parent_path();
  return (repository / ".." / "shared").lexically_normal().string();
}

// Random weights shaped like the real files: He-scaled convolutions, small non-negative lin weights (the
// trained ones are non-negative too).
inline std::map<std::string, at::Tensor> random_lpips_weights(metrics::LpipsNet net, uint64_t seed) {
  at::manual_seed(seed);
  std::map<std::string, at::Tensor> weights;
  for (const auto& [name, shape] : metrics::lpips_weight_shapes(net)) {
    at::Tensor t;
    if (name.rfind("lin", 0) == 0) {
      t = at::rand(shape, at::kFloat) * 0.1;
    } else if (shape.size() == 1) {
      t = at::randn(shape, at::kFloat) * 0.05;
    } else {
      t = at::randn(shape, at::kFloat) * std::sqrt(2.0 / double(shape[1] * shape[2] * shape[3]));
    }
    weights.emplace(name, t);
  }
  return weights;
}

inline void write_bytes(const std::string& path, const std::string& bytes) {
  std::ofstream file(path, std::ios::binary | std::ios::trunc);
  file.write(bytes.data(), std::streamsize(bytes.size()));
}

// The safetensors layout of a header object and the concatenated data (the header length as u64 little-endian).
inline std::string safetensors_bytes(const nlohmann::json& header, const std::string& data) {
  const std::string text = header.dump();
  std::string bytes(8, '\0');
  for (int i = 0; i < 8; ++i) bytes[i] = char((uint64_t(text.size()) >> (8 * i)) & 0xff);
  return bytes + text + data;
}

// float32 tensors (names sorted, contiguous data) in safetensors form, with optional metadata.
inline std::string safetensors_bytes(const std::map<std::string, at::Tensor>& tensors,
                                     const std::map<std::string, std::string>& metadata = {}) {
  nlohmann::json header = nlohmann::json::object();
  std::string data;
  for (const auto& [name, tensor] : tensors) {
    const at::Tensor t = tensor.to(at::kFloat).contiguous();
    const size_t begin = data.size();
    data.append(static_cast<const char*>(t.data_ptr()), t.numel() * sizeof(float));
    header[name] = {{"dtype", "F32"}, {"shape", t.sizes().vec()}, {"data_offsets", {begin, data.size()}}};
  }
  if (!metadata.empty()) header["__metadata__"] = metadata;
  return safetensors_bytes(header, data);
}

// A fresh folder for files a test writes.
inline std::string temporary_folder(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::temp_directory_path() / ("sfgs_test_metrics_" + name);
  remove_folder_tree(dir.string());
  std::filesystem::create_directories(dir);
  return dir.string();
}

// `call` must throw a c10::Error whose message contains every one of `parts`.
inline void expect_error(const std::function<void()>& call, std::initializer_list<std::string> parts) {
  try {
    call();
    ADD_FAILURE() << "expected an error containing '" << *parts.begin() << "'";
  } catch (const c10::Error& e) {
    const std::string message = e.what_without_backtrace();
    for (const std::string& part : parts)
      EXPECT_NE(message.find(part), std::string::npos) << "missing '" << part << "' in: " << message;
  }
}

}  // namespace sfgs::testing
