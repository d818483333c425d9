#pragma once
// MP4 output through OpenCV when the build has it; without OpenCV the writer reports itself unavailable and the
// frames stay as PNGs.
#include <memory>
#include <string>

#include <ATen/core/Tensor.h>

namespace sfgs::cli {

class VideoWriter {
 public:
  VideoWriter(const std::string& path, int width, int height, double fps, bool overwrite);
  ~VideoWriter();
  bool available() const;
  void add(const at::Tensor& image);  // (H, W, 3) float in [0, 1]
  // Finishes the file and moves it into place; false when no video could be written.
  bool close();

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace sfgs::cli
