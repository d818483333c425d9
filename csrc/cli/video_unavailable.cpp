// Stands in for video_opencv.cpp in builds without OpenCV.
#include <ATen/core/Tensor.h>

#include "cli/video.h"

namespace sfgs::cli {

struct VideoWriter::State {};

VideoWriter::VideoWriter(const std::string&, int, int, double, bool) : state_(std::make_unique<State>()) {}
VideoWriter::~VideoWriter() = default;
bool VideoWriter::available() const { return false; }
void VideoWriter::add(const at::Tensor&) {}
bool VideoWriter::close() { return false; }

}  // namespace sfgs::cli
