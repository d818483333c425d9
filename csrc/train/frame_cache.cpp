#include "train/frame_cache.h"

#include <ATen/ATen.h>

#include "common/constants.h"
#include "train/constants.h"

namespace sfgs::train {

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
  return at::cat({f.image, f.mask.unsqueeze(2)}, 2).mul(kEightBitMax).round().to(at::kByte);
}

bool FrameCache::keep(int64_t index, const at::Tensor& packed) {
  const std::lock_guard<std::mutex> lock(mutex_);
  if (frames_.count(index)) return true;
  if (bytes_ + packed.numel() > kFrameCacheBytes) return false;
  bytes_ += packed.numel();
  frames_[index] = packed;
  return true;
}

int64_t FrameCache::kept() const {
  const std::lock_guard<std::mutex> lock(mutex_);
  return int64_t(frames_.size());
}

at::Tensor FrameCache::get(int64_t index) {
  {
    const std::lock_guard<std::mutex> lock(mutex_);
    const auto it = frames_.find(index);
    if (it != frames_.end()) {
      // Page-locked here, on the caller's thread, the first time it is asked for: the decoding thread makes no CUDA
      // call, which a CUDA graph being recorded meanwhile would not allow. A kept frame is never written again, so
      // an upload in flight reads it safely.
      if (page_locked_ && !it->second.is_pinned()) it->second = it->second.pin_memory();
      return it->second;
    }
  }
  const at::Tensor packed = decode(index);
  if (!keep(index, packed)) return page_locked_ ? packed.pin_memory() : packed;
  return get(index);
}

void FrameCache::decode_ahead() {
  for (int64_t index : ahead_) {
    if (stop_) return;
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      if (frames_.count(index)) continue;
    }
    try {
      if (!keep(index, decode(index))) return;  // the cache is full
    } catch (const std::exception&) {
      return;  // get() reads the frame again and tells its error
    }
  }
}

}  // namespace sfgs::train
