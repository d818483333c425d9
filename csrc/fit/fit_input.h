#pragma once
// What `sfgs fit` reads from a video folder: per-frame whole-body keypoints (keypoints_whole_body/<frame>.json),
// each frame's intrinsics (NeuMan's sparse/cameras.txt, an sfgs dataset.json, or estimated from the image size),
// the person masks when there are any, and the dataset's shape when it has one. Errors name the file and what was
// expected.
#include <ATen/core/Tensor.h>

#include <cstdint>
#include <string>
#include <vector>

namespace sfgs::fit {

struct FitFrame {
  int64_t number = 0;             // the frame number of its keypoint file
  std::string mask_path;          // empty: no mask
  bool mask_white_person = true;  // false: NeuMan segmentation (person black)
  double fx = 0, fy = 0, cx = 0, cy = 0;
  int64_t width = 0, height = 0;
};

struct FitInput {
  std::string folder;
  std::vector<FitFrame> frames;  // by frame number
  at::Tensor keypoints;          // (B, 133, 3) float32 [x, y, score]
  at::Tensor betas;  // the dataset's shared shape (smplx_optimized/shape_param.json, dataset.json); may be undefined
  std::string camera_source;  // where the intrinsics came from, for the log
};

// `focal` > 0 replaces the focal length of every frame (pixels); 0 keeps the dataset's, or, where the folder has no
// cameras, takes max(width, height) with the principal point at the image centre.
FitInput read_fit_input(const std::string& folder, double focal);

}  // namespace sfgs::fit
