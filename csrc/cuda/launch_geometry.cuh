#pragma once
// Host-side helpers the torch-free kernel files of the fused ops share (group_norm.cu, feature_fusion.cu,
// gathered_first_layer.cu, column_sum.cu): launch checks, the multiprocessor count that sizes their grid-stride
// launches, and the alignment test of their float4 paths. Errors name the op: "sfgs <owner>: ...".
#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>

#include <cuda_runtime_api.h>

namespace sfgs::cuda_launch {

inline void check(cudaError_t status, const char* owner, const std::string& what) {
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs ") + owner + ": " + what + " failed: " + cudaGetErrorString(status));
}

// The latest launch's error, if any.
inline void check_launch(const char* owner, const std::string& kernel) {
  check(cudaGetLastError(), owner, kernel + " launch");
}

inline int device_attribute(cudaDeviceAttr attribute, int device, const char* owner, const char* what) {
  int value = 0;
  check(cudaDeviceGetAttribute(&value, attribute, device), owner,
        std::string("reading the ") + what + " of CUDA device " + std::to_string(device));
  return value;
}

inline int64_t multiprocessors(int device, const char* owner) {
  return device_attribute(cudaDevAttrMultiProcessorCount, device, owner, "multiprocessor count");
}

// Blocks of a grid-stride launch over `work` items, `work_per_block` a block at a time: enough for the work, at most
// `blocks_per_sm` a multiprocessor (the loop strides beyond), at least one.
inline int64_t grid_stride_blocks(int64_t work, int64_t work_per_block, int64_t blocks_per_sm, int device,
                                  const char* owner) {
  const int64_t needed = (work + work_per_block - 1) / work_per_block;
  return std::max<int64_t>(1, std::min<int64_t>(needed, multiprocessors(device, owner) * blocks_per_sm));
}

// Whether a float4 load or store at p is aligned (null counts as aligned: an absent array is never read).
inline bool aligned16(const void* p) { return reinterpret_cast<uintptr_t>(p) % 16 == 0; }

}  // namespace sfgs::cuda_launch
