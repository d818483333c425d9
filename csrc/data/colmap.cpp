#include "data/colmap.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include <c10/util/Exception.h>

namespace sfgs::data {
namespace {

std::vector<std::string> data_lines(const std::string& path) {
  std::ifstream in(path);
  TORCH_CHECK(in.good(), "cannot open COLMAP file '", path, "'");
  std::vector<std::string> lines;
  for (std::string line; std::getline(in, line);)
    if (line.empty() || line[0] != '#') lines.push_back(line);
  return lines;
}

bool blank(const std::string& line) { return line.find_first_not_of(" \t\r") == std::string::npos; }

}  // namespace

std::map<int64_t, ColmapIntrinsics> read_colmap_cameras(const std::string& path) {
  std::map<int64_t, ColmapIntrinsics> cameras;
  int line_number = 0;
  for (const std::string& line : data_lines(path)) {
    ++line_number;
    if (blank(line)) continue;
    std::istringstream s(line);
    int64_t id = 0;
    std::string model;
    ColmapIntrinsics c{};
    s >> id >> model >> c.width >> c.height;
    TORCH_CHECK(!s.fail(), "'", path, "': cannot parse camera line ", line_number, ": '", line, "'");
    if (model == "PINHOLE") {
      s >> c.fx >> c.fy >> c.cx >> c.cy;
    } else if (model == "SIMPLE_PINHOLE") {
      s >> c.fx >> c.cx >> c.cy;
      c.fy = c.fx;
    } else {
      TORCH_CHECK(false, "'", path, "': camera model ", model,
                  " has lens distortion; sfgs needs PINHOLE or "
                  "SIMPLE_PINHOLE (undistort the images first)");
    }
    TORCH_CHECK(!s.fail() && c.fx > 0 && c.fy > 0 && c.width > 0 && c.height > 0, "'", path,
                "': bad camera parameters on line ", line_number, ": '", line, "'");
    cameras[id] = c;
  }
  TORCH_CHECK(!cameras.empty(), "'", path, "' holds no camera");
  return cameras;
}

std::vector<ColmapImage> read_colmap_images(const std::string& path) {
  const std::vector<std::string> lines = data_lines(path);
  std::vector<ColmapImage> images;
  // Each image has two lines, the second (its 2D points) possibly empty.
  for (size_t i = 0; i < lines.size(); ++i) {
    if (blank(lines[i])) continue;
    std::istringstream s(lines[i]);
    int64_t id = 0;
    double qw, qx, qy, qz, tx, ty, tz;
    ColmapImage image;
    s >> id >> qw >> qx >> qy >> qz >> tx >> ty >> tz >> image.camera_id >> image.name;
    TORCH_CHECK(!s.fail(), "'", path, "': cannot parse image line '", lines[i], "'");
    const double norm = std::sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
    TORCH_CHECK(norm > 0, "'", path, "': image '", image.name, "' has a zero quaternion");
    qw /= norm;
    qx /= norm;
    qy /= norm;
    qz /= norm;
    image.world_to_camera = {1 - 2 * (qy * qy + qz * qz),
                             2 * (qx * qy - qw * qz),
                             2 * (qx * qz + qw * qy),
                             tx,
                             2 * (qx * qy + qw * qz),
                             1 - 2 * (qx * qx + qz * qz),
                             2 * (qy * qz - qw * qx),
                             ty,
                             2 * (qx * qz - qw * qy),
                             2 * (qy * qz + qw * qx),
                             1 - 2 * (qx * qx + qy * qy),
                             tz,
                             0,
                             0,
                             0,
                             1};
    images.push_back(image);
    ++i;  // skip the points line
  }
  return images;
}

}  // namespace sfgs::data
