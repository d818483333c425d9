#pragma once
// The SFGS objective: L_img = l1 (L1 + (1 - SSIM) + LPIPS) + la * LAB + lg * gradient on the rendered image, and the
// geometry regularisers (offset and scale L2 with per-part weights, mesh Laplacian of offsets and scales).
#include <map>
#include <optional>
#include <string>

#include <ATen/core/Tensor.h>

#include "metrics/lpips.h"
#include "model/avatar.h"
#include "train/train_config.h"

namespace sfgs::train {

// Named loss terms; "total" is their weighted sum.
using LossTerms = std::map<std::string, at::Tensor>;

class ImageLoss {
 public:
  // LPIPS (AlexNet) is loaded when weights.use_lpips; when its weights cannot be found `lpips_status()` says why and
  // the term is left out (the trainer logs it).
  ImageLoss(const LossWeights& weights, at::Device device);
  // prediction and target (H, W, 3) in [0, 1]; adds "l1", "ssim", "lpips", "lab", "gradient" and "image". Without
  // `with_lpips` the image term leaves LPIPS out, and there is no "lpips".
  void add_terms(const at::Tensor& prediction, const at::Tensor& target, LossTerms& terms,
                 bool with_lpips = true) const;
  const std::string& lpips_status() const { return lpips_status_; }

 private:
  LossWeights weights_;
  std::optional<metrics::Lpips> lpips_;
  std::string lpips_status_;
};

class Regularisers {
 public:
  Regularisers(const LossWeights& weights, const at::Tensor& part_labels, const at::Tensor& faces, at::Device device);
  // Adds "mean_offset", "scale", "laplacian_mean", "laplacian_scale" (weighted).
  void add_terms(const model::AvatarOutput& out, LossTerms& terms) const;

 private:
  LossWeights weights_;
  at::Tensor mean_part_weight_, scale_part_weight_, laplacian_part_weight_;  // (N) per Gaussian
  at::Tensor neighbours_, neighbour_counts_;
};

// Sum of the terms' values (the image terms and the regularisers) into "total".
at::Tensor total_loss(LossTerms& terms);

}  // namespace sfgs::train
