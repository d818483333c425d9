// Stands in for depth_tiff.cpp in builds without OpenCV and in the Python module, which links no OpenCV.
#include <string>

#include <ATen/ATen.h>

namespace sfgs::data {

at::Tensor read_depth_tiff(const std::string& path) {
  TORCH_CHECK(false, "cannot read depth image '", path, "': TIFF needs OpenCV, which the Python module never links ",
              "and this build may lack (the sfgs executable reads it where CMake found OpenCV)");
}

}  // namespace sfgs::data
