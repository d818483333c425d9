#pragma once
// MP4 output through OpenCV when the build has it; without OpenCV (or without its MP4 encoder) the writer reports
// itself unavailable and the frames stay as PNGs. The file is encoded into a temporary and moved into place only
// once its structure is complete, so a full disk is an error, never a truncated render.mp4.
#include <memory>
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

}  // namespace sfgs::cli
