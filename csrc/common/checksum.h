#pragma once
// CRC-32 (zlib's) of bytes and of tensors: checkpoints carry one per tensor so that a damaged file is named as damaged
// instead of evaluating to wrong numbers, and datasets get a fingerprint so a run cannot resume on other data.
#include <cstddef>
#include <cstdint>

#include <ATen/core/Tensor.h>

namespace sfgs {

// CRC-32 of `size` bytes, continuing from `crc` (0 to start).
uint32_t crc32_of(const void* data, std::size_t size, uint32_t crc = 0);
// CRC-32 of a tensor's values (its bytes in row-major order, after a copy to the host if needed), continuing `crc`.
uint32_t crc32_of(const at::Tensor& tensor, uint32_t crc = 0);

}  // namespace sfgs
