#include <sys/statvfs.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <stdexcept>

#include <ATen/ATen.h>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "cli/video.h"
#include "common/constants.h"
#include "common/atomic_file.h"

namespace sfgs::cli {
namespace fs = std::filesystem;

namespace {

// Why an MP4 file is not complete, or empty when it is: its top-level boxes must tile the file exactly and include
// the header (moov) and the media data (mdat). An encoder that hit a full disk leaves a file that fails this (no
// moov, or a box running past the end), and OpenCV does not report the failed writes.
std::string mp4_problem(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return "it cannot be read back";
  const uint64_t size = fs::file_size(path);
  std::set<std::string> boxes;
  uint64_t at = 0;
  while (at < size) {
    unsigned char header[16];
    in.seekg(std::streamoff(at));
    if (size - at < 8 || !in.read(reinterpret_cast<char*>(header), 8)) return "a box header is cut off";
    uint64_t box = (uint64_t(header[0]) << 24) | (uint64_t(header[1]) << 16) | (uint64_t(header[2]) << 8) | header[3];
    const std::string type(reinterpret_cast<char*>(header + 4), 4);
    if (box == 1) {  // 64-bit size follows
      if (!in.read(reinterpret_cast<char*>(header + 8), 8)) return "a box header is cut off";
      box = 0;
      for (int i = 8; i < 16; ++i) box = (box << 8) | header[i];
    } else if (box == 0) {
      box = size - at;  // the last box runs to the end of the file
    }
    if (box < 8 || box > size - at) return "box '" + type + "' runs past the end of the file";
    boxes.insert(type);
    at += box;
  }
  for (const char* needed : {"moov", "mdat"})
    if (!boxes.count(needed)) return std::string("it has no '") + needed + "' box";
  return "";
}

std::string free_space(const std::string& path) {
  struct statvfs s {};
  const fs::path folder = fs::path(path).has_parent_path() ? fs::path(path).parent_path() : fs::path(".");
  if (::statvfs(folder.c_str(), &s) != 0) return "";
  char text[96];
  std::snprintf(text, sizeof(text), "; %.1f MB free on that disk", double(s.f_bavail) * double(s.f_frsize) / 1e6);
  return text;
}

}  // namespace

struct VideoWriter::State {
  cv::VideoWriter writer;
  std::string path, temporary;
  int64_t frames = 0;
};

VideoWriter::VideoWriter(const std::string& path, int width, int height, double fps, bool overwrite)
    : state_(std::make_unique<State>()) {
  if (!overwrite && fs::exists(path))
    throw std::runtime_error("refusing to overwrite existing file '" + path + "' (pass --force to replace it)");
  state_->path = path;
  state_->temporary = temporary_path(path, ".mp4");
  if (state_->writer.open(state_->temporary, cv::VideoWriter::fourcc('m', 'p', '4', 'v'), fps, cv::Size(width, height)))
    return;
  // No writer: either this OpenCV has no MP4 encoder (PNG frames only, said at the end), or the file cannot be made.
  FILE* probe = std::fopen(state_->temporary.c_str(), "wb");
  const int error = errno;
  if (probe) std::fclose(probe);
  std::remove(state_->temporary.c_str());
  if (!probe) throw std::runtime_error("cannot write video '" + path + "': " + std::strerror(error));
}

VideoWriter::~VideoWriter() {
  if (state_ && state_->writer.isOpened()) state_->writer.release();
  if (state_) std::remove(state_->temporary.c_str());
}

bool VideoWriter::available() const { return state_->writer.isOpened(); }

void VideoWriter::add(const at::Tensor& image) {
  if (!available()) return;
  const at::Tensor bgr =
      image.detach().cpu().flip({2}).clamp(0, 1).mul(kEightBitMax).round().to(at::kByte).contiguous();
  cv::Mat frame(int(bgr.size(0)), int(bgr.size(1)), CV_8UC3, bgr.data_ptr<uint8_t>());
  state_->writer.write(frame);
  ++state_->frames;
}

bool VideoWriter::close() {
  if (!available()) return false;
  state_->writer.release();
  const std::string problem = mp4_problem(state_->temporary);
  if (!problem.empty()) {
    const std::string bytes = fs::exists(state_->temporary) ? std::to_string(fs::file_size(state_->temporary)) : "0";
    std::remove(state_->temporary.c_str());
    throw std::runtime_error("could not write video '" + state_->path + "': the encoded file (" + bytes + " bytes, " +
                             std::to_string(state_->frames) + " frames) is incomplete: " + problem +
                             " (a full disk or a file size limit?" + free_space(state_->path) + ")");
  }
  commit_file(state_->temporary, state_->path);
  return true;
}

double video_frame_rate(const std::string& path) {
  cv::VideoCapture capture(path);
  const double rate = capture.isOpened() ? capture.get(cv::CAP_PROP_FPS) : 0.0;
  return std::isfinite(rate) && rate > 0 ? rate : 0.0;
}

std::function<std::optional<at::Tensor>()> read_video(const std::string& path) {
  auto capture = std::make_shared<cv::VideoCapture>(path);
  TORCH_CHECK(capture->isOpened(), "cannot read video '", path, "' (missing, or a format OpenCV cannot decode)");
  return [capture, path]() -> std::optional<at::Tensor> {
    cv::Mat bgr;
    if (!capture->read(bgr) || bgr.empty()) return std::nullopt;
    TORCH_CHECK(bgr.type() == CV_8UC3, "video '", path, "': expected 8-bit colour frames");
    cv::Mat rgb;
    cv::cvtColor(bgr, rgb, cv::COLOR_BGR2RGB);
    return at::from_blob(rgb.data, {rgb.rows, rgb.cols, 3}, at::kByte).to(at::kFloat).div_(kEightBitMax);
  };
}

}  // namespace sfgs::cli
