#include "train/frame_cache.h"

#include <ATen/ATen.h>

#include "common/constants.h"

namespace sfgs::train {

// Frames kept decoded in memory (8-bit) up to this many bytes; beyond it they are read from disk when drawn.
constexpr int64_t kFrameCacheBytes = int64_t(2) << 30;

FrameCache::FrameCache(const data::Dataset& dataset, std::vector<int64_t> ahead, bool page_locked)
    : dataset_(dataset), ahead_(std::move(ahead)), page_locked_(page_locked) {
  if (!ahead_.empty()) worker_ = std::thread([this] { decode_ahead(); });
}

FrameCache::~FrameCache() {
  stop_ = true;
  if (worker_.joinable()) worker_.join();
}

at::Tensor FrameCache::decode(int64_t index) const {
  const data::Frame f = dataset_.load(index);
  const at::Tensor packed = at::cat({f.image, f.mask.unsqueeze(2)}, 2).mul(kEightBitMax).round().to(at::kByte);
  // A kept frame is never written again, so an upload in flight reads it safely.
  return page_locked_ ? packed.pin_memory() : packed;
}

at::Tensor FrameCache::keep(int64_t index, at::Tensor packed) {
  const std::lock_guard<std::mutex> lock(mutex_);
  const auto it = frames_.find(index);
  if (it != frames_.end()) return it->second;
  if (bytes_ + packed.numel() <= kFrameCacheBytes) {
    bytes_ += packed.numel();
    frames_[index] = packed;
  }
  return packed;
}

at::Tensor FrameCache::get(int64_t index) {
  {
    const std::lock_guard<std::mutex> lock(mutex_);
    const auto it = frames_.find(index);
    if (it != frames_.end()) return it->second;
  }
  return keep(index, decode(index));
}

void FrameCache::decode_ahead() {
  for (int64_t index : ahead_) {
    if (stop_) return;
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      if (bytes_ >= kFrameCacheBytes) return;
      if (frames_.count(index)) continue;
    }
    try {
      keep(index, decode(index));
    } catch (const std::exception&) {
      return;  // get() reads the frame again and tells its error
    }
  }
}

}  // namespace sfgs::train
