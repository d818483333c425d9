#include "cli/frame_encoder.h"

#include <algorithm>

#include <ATen/ATen.h>

#include "common/constants.h"
#include "common/tensor_description.h"
#include "data/image_io.h"

namespace sfgs::cli {
namespace {

// Frames a worker may have queued ahead of it: enough to ride over a slow PNG, few enough to bound the memory.
constexpr size_t kQueuedFramesPerThread = 4;

}  // namespace

at::Tensor eight_bit_image(const at::Tensor& image) {
  TORCH_CHECK(image.dim() == 3 && image.size(2) == 3 && at::isFloatingType(image.scalar_type()),
              "eight_bit_image: expected an (H, W, 3) floating image, got ", describe(image));
  const at::Tensor bytes = image.detach().to(at::kFloat).clamp(0, 1).mul(kEightBitMax).round().to(at::kByte);
  const at::Tensor finite = image.isfinite().all();
  if (!image.is_cuda()) {
    TORCH_CHECK(finite.item<bool>(), "the rendered image has NaN or Inf values");
    return bytes.contiguous();
  }
  // Into page-locked memory without waiting; the check's read then waits for the queue, the copy included.
  at::Tensor host = at::empty(bytes.sizes(), at::TensorOptions().dtype(at::kByte).pinned_memory(true));
  host.copy_(bytes, /*non_blocking=*/true);
  TORCH_CHECK(finite.item<bool>(), "the rendered image has NaN or Inf values");
  return host;
}

FrameEncoder::FrameEncoder(VideoWriter* video, bool overwrite, int png_threads)
    : video_(video), overwrite_(overwrite), capacity_(kQueuedFramesPerThread * size_t(std::max(png_threads, 1) + 1)) {
  const auto write_png = [this](const at::Tensor& image, const Frame& f) {
    data::write_png(f.path, image, overwrite_);
  };
  const auto add_to_video = [this](const at::Tensor& image, const Frame&) { video_->add(image); };
  for (int i = 0; i < std::max(png_threads, 1); ++i)
    workers_.emplace_back([this, write_png] { drain(pngs_, write_png); });
  if (video_ != nullptr) workers_.emplace_back([this, add_to_video] { drain(videos_, add_to_video); });
}

FrameEncoder::~FrameEncoder() {
  {
    const std::lock_guard<std::mutex> lock(mutex_);
    closing_ = true;
  }
  changed_.notify_all();
  for (std::thread& t : workers_)
    if (t.joinable()) t.join();
}

void FrameEncoder::add(const std::string& png_path, const at::Tensor& eight_bit) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [&] { return error_ || pngs_.size() + videos_.size() < capacity_; });
  if (error_) std::rethrow_exception(error_);
  pngs_.push_back({png_path, eight_bit});
  if (video_ != nullptr) videos_.push_back({png_path, eight_bit});
  lock.unlock();
  changed_.notify_all();
}

void FrameEncoder::finish() {
  {
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait(lock, [&] { return error_ || (pngs_.empty() && videos_.empty() && busy_ == 0); });
    closing_ = true;
  }
  changed_.notify_all();
  for (std::thread& t : workers_)
    if (t.joinable()) t.join();
  rethrow();
}

void FrameEncoder::fail(std::exception_ptr error) {
  {
    const std::lock_guard<std::mutex> lock(mutex_);
    if (!error_) error_ = error;
    pngs_.clear();
    videos_.clear();
  }
  changed_.notify_all();
}

void FrameEncoder::rethrow() {
  const std::lock_guard<std::mutex> lock(mutex_);
  if (error_) std::rethrow_exception(error_);
}

void FrameEncoder::drain(std::deque<Frame>& queue, const std::function<void(const at::Tensor&, const Frame&)>& encode) {
  for (;;) {
    Frame frame;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [&] { return closing_ || error_ || !queue.empty(); });
      if (queue.empty()) return;
      frame = std::move(queue.front());
      queue.pop_front();
      ++busy_;
    }
    try {
      encode(frame.image.to(at::kFloat).div(kEightBitMax), frame);
    } catch (...) {
      fail(std::current_exception());
    }
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      --busy_;
    }
    changed_.notify_all();
  }
}

}  // namespace sfgs::cli
