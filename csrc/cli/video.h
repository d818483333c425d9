#pragma once
// Video files read and written through OpenCV when the build has it. MP4 output: without OpenCV (or without its MP4
// encoder) the writer reports itself unavailable and the frames stay as PNGs. The file is encoded into a temporary and
// moved into place only once its structure is complete, so a full disk is an error, never a truncated render.mp4.
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>

#include <ATen/core/Tensor.h>

namespace sfgs::cli {

class VideoWriter {
 public:
  // Throws when the file cannot be created (a missing folder, no permission, a full disk).
  VideoWriter(const std::string& path, int width, int height, double fps, bool overwrite);
  ~VideoWriter();
  bool available() const;
  void add(const at::Tensor& image);  // (H, W, 3) float in [0, 1]
  // Finishes the file, checks it is complete and moves it into place; false when no encoder is available. Throws
  // naming the file (and the free space) when the encoded file is incomplete; the temporary is removed then.
  bool close();

 private:
  struct State;
  std::unique_ptr<State> state_;
};

// The frames of a video file in order, each (H, W, 3) float32 in [0, 1] on the CPU, none at the end. Throws naming
// the file when it cannot be opened, and in a build without OpenCV (give a folder of frames instead).
std::function<std::optional<at::Tensor>()> read_video(const std::string& path);
// The video's frame rate as its file states it (0 when it states none).
double video_frame_rate(const std::string& path);

}  // namespace sfgs::cli
