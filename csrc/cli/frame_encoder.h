#pragma once
// `sfgs render`'s output stage: the rendered frames' PNGs and the video are encoded on background threads while the
// GPU renders the next frames, so the render's pace is the GPU's and the encoding's the CPU cores'. PNGs are
// encoded in parallel; the video takes the frames in order on a thread of its own. Frames arrive as 8-bit images
// (quantised on the device, a quarter of the bytes to copy back); the queue is bounded, so a slow disk holds the
// render back instead of filling memory.
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <ATen/core/Tensor.h>

#include "cli/video.h"

namespace sfgs::cli {

// An (H, W, 3) float image in [0, 1] as the (H, W, 3) uint8 image write_png makes of it (the same rounding), on
// the CPU; the image may be on any device and is checked to be finite.
at::Tensor eight_bit_image(const at::Tensor& image);

class FrameEncoder {
 public:
  // video may be null (no MP4); png_threads >= 1.
  FrameEncoder(VideoWriter* video, bool overwrite, int png_threads);
  ~FrameEncoder();  // waits for the queued frames (errors are then dropped: call finish() to see them)
  FrameEncoder(const FrameEncoder&) = delete;
  FrameEncoder& operator=(const FrameEncoder&) = delete;

  // Queues one frame (uint8 (H, W, 3) on the CPU) for `png_path`; blocks while the queue is full. Throws the first
  // error a worker met.
  void add(const std::string& png_path, const at::Tensor& eight_bit);
  // Waits for every queued frame; throws the first error a worker met.
  void finish();

 private:
  struct Frame {
    std::string path;
    at::Tensor image;
  };
  // A worker: encodes the frames of `queue` (as float images in [0, 1]) until the encoder closes.
  void drain(std::deque<Frame>& queue, const std::function<void(const at::Tensor&, const Frame&)>& encode);
  void fail(std::exception_ptr error);
  void rethrow();

  VideoWriter* video_;
  bool overwrite_;
  size_t capacity_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Frame> pngs_, videos_;
  int64_t busy_ = 0;  // frames taken by a worker and not yet done
  bool closing_ = false;
  std::exception_ptr error_;
  std::vector<std::thread> workers_;
};

}  // namespace sfgs::cli
