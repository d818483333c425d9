// Stands in for depth_tiff.cpp in builds without OpenCV.
#include <string>

#include <ATen/ATen.h>

namespace sfgs::data {

at::Tensor read_depth_tiff(const std::string& path) {
  TORCH_CHECK(false, "cannot read depth image '", path, "': this build of sfgs has no OpenCV (needed for TIFF)");
}

}  // namespace sfgs::data
