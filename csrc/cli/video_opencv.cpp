#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include <ATen/ATen.h>
#include <opencv2/videoio.hpp>
#include <unistd.h>

#include "cli/video.h"

namespace sfgs::cli {

struct VideoWriter::State {
  cv::VideoWriter writer;
  std::string path, temporary;
};

VideoWriter::VideoWriter(const std::string& path, int width, int height, double fps, bool overwrite)
    : state_(std::make_unique<State>()) {
  if (!overwrite && std::filesystem::exists(path))
    throw std::runtime_error("refusing to overwrite existing file '" + path + "' (pass --force to replace it)");
  state_->path = path;
  state_->temporary = path + ".tmp-" + std::to_string(::getpid()) + ".mp4";
  state_->writer.open(state_->temporary, cv::VideoWriter::fourcc('m', 'p', '4', 'v'), fps, cv::Size(width, height));
}

VideoWriter::~VideoWriter() {
  if (state_ && state_->writer.isOpened()) {
    state_->writer.release();
    std::remove(state_->temporary.c_str());
  }
}

bool VideoWriter::available() const { return state_->writer.isOpened(); }

void VideoWriter::add(const at::Tensor& image) {
  if (!available()) return;
  const at::Tensor bgr = image.detach().cpu().flip({2}).clamp(0, 1).mul(255).round().to(at::kByte).contiguous();
  cv::Mat frame(int(bgr.size(0)), int(bgr.size(1)), CV_8UC3, bgr.data_ptr<uint8_t>());
  state_->writer.write(frame);
}

bool VideoWriter::close() {
  if (!available()) return false;
  state_->writer.release();
  std::filesystem::rename(state_->temporary, state_->path);
  return true;
}

}  // namespace sfgs::cli
