#pragma once
// COLMAP's text model (cameras.txt, images.txt), as NeuMan ships it.
#include <array>
#include <map>
#include <string>
#include <vector>

#include "ops/splat/splat.h"

namespace sfgs::data {

struct ColmapIntrinsics {
  int64_t width, height;
  double fx, fy, cx, cy;
};

struct ColmapImage {
  std::string name;
  int64_t camera_id;
  std::array<double, 16> world_to_camera;  // row-major, from the stored quaternion and translation
};

// Reads PINHOLE and SIMPLE_PINHOLE cameras; models with distortion are refused (the splatting camera is a pinhole).
std::map<int64_t, ColmapIntrinsics> read_colmap_cameras(const std::string& path);
std::vector<ColmapImage> read_colmap_images(const std::string& path);

}  // namespace sfgs::data
