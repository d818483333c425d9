// Stands in for video_opencv.cpp in builds without OpenCV.
#include <ATen/core/Tensor.h>
#include <c10/util/Exception.h>

#include "cli/video.h"

namespace sfgs::cli {

struct VideoWriter::State {};

VideoWriter::VideoWriter(const std::string&, int, int, double, bool) : state_(std::make_unique<State>()) {}
VideoWriter::~VideoWriter() = default;
bool VideoWriter::available() const { return false; }
void VideoWriter::add(const at::Tensor&) {}
bool VideoWriter::close() { return false; }

double video_frame_rate(const std::string&) { return 0.0; }

std::function<std::optional<at::Tensor>()> read_video(const std::string& path) {
  TORCH_CHECK(false, "cannot read video '", path,
              "': this build of sfgs has no OpenCV (libopencv-dev); give a folder of its frames (.png, .jpg)");
}

}  // namespace sfgs::cli
