// X-Humans depth maps are TIFF files; OpenCV reads them.
#include <string>

#include <ATen/ATen.h>
#include <opencv2/imgcodecs.hpp>

namespace sfgs::data {

at::Tensor read_depth_tiff(const std::string& path) {
  cv::Mat depth = cv::imread(path, cv::IMREAD_UNCHANGED | cv::IMREAD_ANYDEPTH);
  TORCH_CHECK(!depth.empty(), "cannot read depth image '", path, "'");
  TORCH_CHECK(depth.channels() == 1, "depth image '", path, "' must have one channel, got ", depth.channels());
  cv::Mat as_float;
  depth.convertTo(as_float, CV_32F);
  return at::from_blob(as_float.data, {as_float.rows, as_float.cols}, at::kFloat).clone();
}

}  // namespace sfgs::data
