#pragma once
// The training frames as 8-bit host tensors (image and mask in one (H, W, 4)), decoded once and kept up to
// kFrameCacheBytes (page-locked for a CUDA run, so each upload is asynchronous). A background thread decodes the
// training frames ahead of the steps, so a step rarely waits for a PNG: with recorded steps (train/step_graphs.h) the
// host would otherwise decode while the GPU idles. The thread makes no CUDA call.
#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <thread>
#include <vector>

#include <ATen/core/Tensor.h>

#include "data/dataset.h"
#include "train/constants.h"

namespace sfgs::train {

class FrameCache {
 public:
  // `ahead`: the frames the background thread decodes, in order (none: decoding happens only when asked).
  FrameCache(const data::Dataset& dataset, std::vector<int64_t> ahead, bool page_locked);
  ~FrameCache();  // stops the background thread (after the frame it is decoding)
  FrameCache(const FrameCache&) = delete;
  FrameCache& operator=(const FrameCache&) = delete;

  // Frame `index`: kept, or decoded now (and kept while the cache has room). A file the background thread could not
  // read is read here again, so its error reaches the caller.
  at::Tensor get(int64_t index);
  // Frames kept so far (decoded ahead or asked for).
  int64_t kept() const;

 private:
  at::Tensor decode(int64_t index) const;
  // Keeps `packed` unless the frame is kept already or there is no room; false: no room.
  bool keep(int64_t index, const at::Tensor& packed);
  void decode_ahead();

  const data::Dataset& dataset_;
  const std::vector<int64_t> ahead_;
  const bool page_locked_;
  mutable std::mutex mutex_;  // guards frames_ and bytes_
  std::map<int64_t, at::Tensor> frames_;
  int64_t bytes_ = 0;
  std::atomic<bool> stop_{false};
  std::thread worker_;
};

}  // namespace sfgs::train
