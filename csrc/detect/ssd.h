#pragma once
// The SSD-style detectors of MediaPipe (the person's, the face's): anchors on feature maps of given strides, boxes and
// keypoints decoded relative to them, and a weighted suppression that keeps the best detection's cluster.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

namespace sfgs::detect {

struct SsdLayout {
  int64_t input = 0;                      // the square input's side, pixels
  std::vector<int64_t> strides;           // of each feature map (maps of one stride merged)
  std::vector<int64_t> anchors_per_cell;  // of each
  int64_t keypoints = 0;                  // per detection
};

// (A, 2) anchor centres in the input's unit square, row by row, cell by cell.
at::Tensor ssd_anchors(const SsdLayout& layout);

// The detections, best first: each a cluster of anchors (the best remaining one and those overlapping it by an IoU
// above 0.3) averaged by score, as (cx, cy, w, h, x0, y0, x1, y1, ...) in the input's unit square; none when no
// anchor's score reaches `min_score`. `boxes` (1, A, 4 + 2 K) and `logits` (1, A, 1) are the network's outputs;
// logits are clipped to +-100 before the sigmoid.
std::vector<std::vector<double>> detections(const at::Tensor& boxes, const at::Tensor& logits,
                                            const at::Tensor& anchors, const SsdLayout& layout, double min_score);

}  // namespace sfgs::detect
