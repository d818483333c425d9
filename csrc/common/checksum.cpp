#include "common/checksum.h"

#include <algorithm>
#include <limits>

#include <ATen/ATen.h>
#include <zlib.h>

namespace sfgs {

uint32_t crc32_of(const void* data, std::size_t size, uint32_t crc) {
  // zlib takes 32-bit lengths: larger buffers go in chunks.
  const auto* bytes = static_cast<const Bytef*>(data);
  uLong value = crc;
  while (size > 0) {
    const std::size_t chunk = std::min<std::size_t>(size, std::numeric_limits<uInt>::max());
    value = ::crc32(value, bytes, uInt(chunk));
    bytes += chunk;
    size -= chunk;
  }
  return uint32_t(value);
}

uint32_t crc32_of(const at::Tensor& tensor, uint32_t crc) {
  const at::Tensor host = tensor.detach().to(at::kCPU).contiguous();
  return crc32_of(host.data_ptr(), std::size_t(host.nbytes()), crc);
}

}  // namespace sfgs
