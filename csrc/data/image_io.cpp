#include "data/image_io.h"
#include "common/constants.h"

#include <filesystem>
#include <set>
#include <stdexcept>
#include <vector>

#include <ATen/ATen.h>

#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STBI_ONLY_PNG
#define STBI_ONLY_JPEG
#include <stb/stb_image.h>
#include <stb/stb_image_write.h>

#include "common/atomic_file.h"

namespace sfgs::data {

at::Tensor read_depth_tiff(const std::string& path);  // depth_tiff.cpp (OpenCV) or its stand-in

namespace {

// stb_image's terse failure reasons ("outofdata") in words, with the reason kept for a search.
std::string why_unreadable(const std::string& path) {
  const std::string reason = stbi_failure_reason() ? stbi_failure_reason() : "unknown";
  static const std::set<std::string> damaged = {"outofdata", "bad zlib header", "bad huffman code",
                                                "no IDAT",   "bad codelengths", "corrupt"};
  static const std::set<std::string> not_an_image = {"unknown image type", "bad png sig", "not PNG"};
  std::string words;
  if (!std::filesystem::exists(path))
    words = "no such file";
  else if (damaged.count(reason))
    words = "the file is cut short or damaged (truncated during a copy or a download?)";
  else if (not_an_image.count(reason))
    words = "not a PNG or JPEG image";
  else if (reason == "can't fopen")
    words = "cannot open the file (permissions?)";
  return words.empty() ? reason : words + " [" + reason + "]";
}

at::Tensor read_8bit(const std::string& path, int channels) {
  int w = 0, h = 0, found = 0;
  stbi_uc* pixels = stbi_load(path.c_str(), &w, &h, &found, channels);
  TORCH_CHECK(pixels != nullptr, "cannot read image '", path, "': ", why_unreadable(path));
  at::Tensor t = at::from_blob(pixels, {h, w, channels}, at::kByte).clone();
  stbi_image_free(pixels);
  return t;
}

}  // namespace

std::pair<int64_t, int64_t> image_size(const std::string& path) {
  int w = 0, h = 0, channels = 0;
  TORCH_CHECK(stbi_info(path.c_str(), &w, &h, &channels) != 0, "cannot read image '", path,
              "': ", why_unreadable(path));
  return {w, h};
}

at::Tensor read_image_rgb(const std::string& path) { return read_8bit(path, 3).to(at::kFloat).div_(kEightBitMax); }

at::Tensor read_mask(const std::string& path, MaskEncoding encoding) {
  if (encoding == MaskEncoding::kDepthForeground) {
    const at::Tensor depth = read_depth_tiff(path);
    return (depth < depth.max()).to(at::kFloat);
  }
  const at::Tensor grey = read_8bit(path, 1).squeeze(2);
  const at::Tensor person = encoding == MaskEncoding::kWhitePerson ? grey > 127 : grey < 128;
  return person.to(at::kFloat);
}

void write_png(const std::string& path, const at::Tensor& image, bool overwrite) {
  TORCH_CHECK(image.defined() && (image.dim() == 2 || (image.dim() == 3 && (image.size(2) == 3 || image.size(2) == 1))),
              "write_png('", path, "'): expected an (H, W) or (H, W, 3) image, got ",
              image.defined() ? image.sizes() : at::IntArrayRef{});
  TORCH_CHECK(image.isfinite().all().item<bool>(), "write_png('", path, "'): the image has NaN or Inf values");
  const at::Tensor bytes =
      image.detach().cpu().to(at::kFloat).clamp(0, 1).mul(kEightBitMax).round().to(at::kByte).contiguous();
  const int h = int(bytes.size(0)), w = int(bytes.size(1)), c = bytes.dim() == 3 ? int(bytes.size(2)) : 1;
  std::vector<unsigned char> encoded;
  const auto append = [](void* context, void* data, int size) {
    auto* out = static_cast<std::vector<unsigned char>*>(context);
    out->insert(out->end(), static_cast<unsigned char*>(data), static_cast<unsigned char*>(data) + size);
  };
  TORCH_CHECK(stbi_write_png_to_func(append, &encoded, w, h, c, bytes.data_ptr<uint8_t>(), w * c) != 0,
              "cannot encode PNG '", path, "'");
  write_file_atomically(path, encoded, overwrite);
}

}  // namespace sfgs::data
