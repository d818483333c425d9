#pragma once
// Image files of datasets and renders: PNG/JPEG through stb (header-only, travels to machines without OpenCV's
// development files), depth TIFF through OpenCV. Every error names the file.
#include <string>
#include <utility>

#include <ATen/core/Tensor.h>

namespace sfgs::data {

// How a mask file encodes the person.
enum class MaskEncoding {
  kWhitePerson,     // 8-bit image, person > 127 (sfgs, SAM masks)
  kBlackPerson,     // 8-bit image, person < 128 (NeuMan segmentations: mask = 1 - seg / 255)
  kDepthForeground  // depth image, person where depth < its maximum (X-Humans)
};

at::Tensor read_image_rgb(const std::string& path);  // (H, W, 3) float32 in [0, 1]
// Width and height from the file's header, without decoding the pixels.
std::pair<int64_t, int64_t> image_size(const std::string& path);
at::Tensor read_mask(const std::string& path, MaskEncoding encoding);  // (H, W) float32 in {0, 1}
// (H, W, 3) or (H, W) float in [0, 1] -> 8-bit PNG, written atomically; values are rounded to the nearest level.
void write_png(const std::string& path, const at::Tensor& image, bool overwrite);
}  // namespace sfgs::data
