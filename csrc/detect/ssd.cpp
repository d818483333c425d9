#include "detect/ssd.h"

#include <algorithm>

#include <ATen/ATen.h>

namespace sfgs::detect {
namespace {

constexpr double kScoreClip = 100;       // logits are clipped to +-this before the sigmoid
constexpr double kSuppressionIoU = 0.3;  // detections overlapping the best by more join its cluster

double iou(const float* a, const float* b) {
  const double w = std::min(a[0] + a[2] / 2, b[0] + b[2] / 2) - std::max(a[0] - a[2] / 2, b[0] - b[2] / 2);
  const double h = std::min(a[1] + a[3] / 2, b[1] + b[3] / 2) - std::max(a[1] - a[3] / 2, b[1] - b[3] / 2);
  if (w <= 0 || h <= 0) return 0;
  const double overlap = w * h;
  return overlap / (double(a[2]) * a[3] + double(b[2]) * b[3] - overlap);
}

}  // namespace

at::Tensor ssd_anchors(const SsdLayout& layout) {
  std::vector<float> centres;
  for (size_t layer = 0; layer < layout.strides.size(); ++layer) {
    const int64_t cells = layout.input / layout.strides[layer];
    for (int64_t row = 0; row < cells; ++row)
      for (int64_t col = 0; col < cells; ++col)
        for (int64_t k = 0; k < layout.anchors_per_cell[layer]; ++k) {
          centres.push_back(float((double(col) + 0.5) / double(cells)));
          centres.push_back(float((double(row) + 0.5) / double(cells)));
        }
  }
  return at::tensor(centres).view({-1, 2});
}

std::vector<std::vector<double>> detections(const at::Tensor& boxes, const at::Tensor& logits,
                                            const at::Tensor& anchors, const SsdLayout& layout, double min_score) {
  const int64_t width = 4 + 2 * layout.keypoints;
  // On the host: a few thousand candidates, of which a handful pass the score.
  const at::Tensor raw = boxes.reshape({-1, width}).cpu();
  TORCH_CHECK(raw.size(0) == anchors.size(0), "detector: ", raw.size(0), " boxes for ", anchors.size(0), " anchors");
  const at::Tensor scores = at::sigmoid(logits.reshape({-1}).cpu().clamp(-kScoreClip, kScoreClip));
  const at::Tensor kept = at::nonzero(scores >= min_score).view({-1});
  std::vector<std::vector<double>> found;
  if (kept.numel() == 0) return found;
  const at::Tensor centres = anchors.index_select(0, kept);
  const at::Tensor offsets = at::cat({centres, at::zeros({kept.size(0), 2}), centres.repeat({1, layout.keypoints})}, 1);
  const at::Tensor decoded = (raw.index_select(0, kept) / double(layout.input) + offsets).contiguous();
  const at::Tensor kept_scores = scores.index_select(0, kept).contiguous();
  const at::Tensor order = std::get<1>(kept_scores.sort(0, true)).contiguous();
  const auto* d = decoded.data_ptr<float>();
  const auto* s = kept_scores.data_ptr<float>();
  std::vector<int64_t> remaining(order.data_ptr<int64_t>(), order.data_ptr<int64_t>() + order.numel());
  while (!remaining.empty()) {
    const int64_t best = remaining.front();
    std::vector<double> mean(size_t(width), 0.0);
    double total = 0;
    std::vector<int64_t> rest;
    for (const int64_t k : remaining) {
      if (k != best && iou(d + best * width, d + k * width) <= kSuppressionIoU) {
        rest.push_back(k);
        continue;
      }
      for (int64_t v = 0; v < width; ++v) mean[size_t(v)] += double(s[k]) * d[k * width + v];
      total += s[k];
    }
    for (double& v : mean) v /= total;
    found.push_back(std::move(mean));
    remaining = std::move(rest);
  }
  return found;
}

}  // namespace sfgs::detect
