#pragma once
// NumPy's .npy arrays and .npz archives (zip files of .npy members, stored or deflated), read and written
// without Python, so the official body-model files, fits and datasets load directly. Supported dtypes:
// float16/32/64, int8/16/32/64, uint8/16/32/64 and bool, either byte order, C or Fortran order. Errors name the
// file, the array and what was expected (docs/body_models.md).
#include <string>
#include <utility>
#include <vector>

#include <ATen/core/Tensor.h>

struct zip;  // libzip's archive handle (zip_t)

namespace sfgs::io {

// An open .npz archive. Members are decompressed one at a time, only when read, so archives holding arrays this
// code cannot represent (pickled objects, strings) still open and their other arrays still read.
class NpzArchive {
 public:
  explicit NpzArchive(const std::string& path);
  ~NpzArchive();
  NpzArchive(NpzArchive&& other) noexcept;
  NpzArchive& operator=(NpzArchive&& other) noexcept;
  NpzArchive(const NpzArchive&) = delete;
  NpzArchive& operator=(const NpzArchive&) = delete;

  const std::string& path() const { return path_; }
  // Array names (member names without ".npy"), in archive order.
  const std::vector<std::string>& keys() const { return keys_; }
  bool contains(const std::string& key) const;
  // The array as a C-contiguous CPU tensor. uint16 widens to int32, uint32 and uint64 to int64 (uint64 values
  // beyond the int64 range are an error).
  at::Tensor read(const std::string& key) const;

 private:
  std::string path_;
  std::vector<std::string> keys_;
  zip* archive_ = nullptr;
};

at::Tensor read_npy(const std::string& path);

enum class NpzCompression { kStored, kDeflate };  // numpy.savez / numpy.savez_compressed

// Writes CPU or CUDA tensors (copied to the host) so numpy.load reads them back with the same names, dtypes,
// shapes and values. The file appears atomically; an existing one is replaced only when `overwrite` is set.
void write_npz(const std::string& path, const std::vector<std::pair<std::string, at::Tensor>>& arrays, bool overwrite,
               NpzCompression compression = NpzCompression::kDeflate);
void write_npy(const std::string& path, const at::Tensor& array, bool overwrite);

}  // namespace sfgs::io
