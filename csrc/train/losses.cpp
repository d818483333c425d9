#include "train/losses.h"

#include <ATen/ATen.h>

#include "body/mesh.h"
#include "body/parts.h"
#include "metrics/image_metrics.h"
#include "ops/pixel_loss/pixel_loss.h"
#include "ops/ssim/ssim.h"

namespace sfgs::train {
namespace {

// Per-Gaussian weights from per-part weights.
at::Tensor part_weights(const at::Tensor& labels, const PartWeights& p, at::Device device) {
  const at::Tensor table = at::tensor({p.body, p.face, p.hands, p.hands}, at::kFloat);
  return table.index_select(0, labels.to(at::kLong).cpu()).to(device);
}

}  // namespace

ImageLoss::ImageLoss(const LossWeights& weights, at::Device device) : weights_(weights) {
  if (!weights.use_lpips) {
    lpips_status_ = "LPIPS loss disabled by the config (loss.use_lpips: false)";
    return;
  }
  const std::string dir = weights.lpips_weights.empty() ? metrics::default_lpips_weights_dir() : weights.lpips_weights;
  try {
    lpips_ = metrics::Lpips::load(metrics::LpipsNet::alex, metrics::lpips_weights_file(metrics::LpipsNet::alex, dir))
                 .to(device, at::kFloat);
    const bool bfloat16 = device.is_cuda() && weights.lpips_bfloat16;
    if (bfloat16) lpips_ = lpips_->with_trunk_dtype(at::kBFloat16);
    lpips_status_ = "LPIPS loss: AlexNet weights from " + dir + (bfloat16 ? " (bfloat16 trunk)" : "");
  } catch (const c10::Error& e) {
    lpips_status_ = std::string("LPIPS loss skipped: ") + e.what_without_backtrace();
  }
}

void ImageLoss::add_terms(const at::Tensor& prediction, const at::Tensor& target, LossTerms& terms,
                          bool with_lpips) const {
  TORCH_CHECK(prediction.sizes() == target.sizes() && prediction.dim() == 3 && prediction.size(2) == 3,
              "ImageLoss: prediction and target must both be (H, W, 3), got ", prediction.sizes(), " and ",
              target.sizes());
  // L1, CIELAB L1 and the image gradients' L1 in one fused op (ops/pixel_loss/pixel_loss.h): their means.
  const at::Tensor pixel = pixel_loss::pixel_losses(prediction, target.detach());
  const at::Tensor l1 = pixel[0];
  // metrics::ssim's zero-border value in one fused pass each way (ops/ssim/ssim.h), which differentiates the prediction
  // only: the target is data.
  const at::Tensor ssim = 1 - ssim::fused_ssim(prediction, target.detach());
  at::Tensor photometric = l1 + ssim;
  terms["l1"] = l1.detach();
  terms["ssim"] = ssim.detach();
  if (with_lpips && lpips_ && std::min(prediction.size(0), prediction.size(1)) >= lpips_->min_image_side()) {
    const at::Tensor lpips = (*lpips_)(prediction, target.detach());
    terms["lpips"] = lpips.detach();
    photometric = photometric + lpips;
  }
  terms["image"] = weights_.image * photometric;
  terms["lab"] = weights_.lab * pixel[1];
  terms["gradient"] = weights_.gradient * (pixel[2] + pixel[3]);
}

Regularisers::Regularisers(const LossWeights& weights, const at::Tensor& part_labels, const at::Tensor& faces,
                           at::Device device)
    : weights_(weights) {
  mean_part_weight_ = part_weights(part_labels, weights.mean_offset_parts, device);
  scale_part_weight_ = part_weights(part_labels, weights.scale_parts, device);
  laplacian_part_weight_ = part_weights(part_labels, weights.laplacian_mean_parts, device);
  const body::VertexNeighbours n = body::vertex_neighbours(faces, part_labels.size(0));
  neighbours_ = n.indices.to(device);
  neighbour_counts_ = n.counts.to(device);
}

void Regularisers::add_terms(const model::AvatarOutput& out, LossTerms& terms) const {
  // Without the structure offset (switched off: undefined) only the head's offsets count.
  const bool structure = out.structure_offset.defined();
  const at::Tensor offsets = structure ? out.mean_offset + out.structure_offset : out.mean_offset;
  at::Tensor squared_offsets = out.mean_offset.square().sum(1);
  if (structure) squared_offsets = squared_offsets + out.structure_offset.square().sum(1);
  terms["mean_offset"] = weights_.mean_offset * (squared_offsets * mean_part_weight_).mean();
  const at::Tensor scales = out.log_scales.exp();
  const at::Tensor squared_scales = structure ? scales.square() + out.scale_offset.square() : scales.square();
  terms["scale"] = weights_.scale * (squared_scales * scale_part_weight_).mean();
  // The Laplacian is linear, so L(rest + offsets) - L(rest) = L(offsets): only the offsets' roughness is penalised.
  const body::VertexNeighbours n{neighbours_, neighbour_counts_};
  terms["laplacian_mean"] =
      weights_.laplacian_mean * (body::uniform_laplacian(n, offsets).square().sum(1) * laplacian_part_weight_).mean();
  terms["laplacian_scale"] = weights_.laplacian_scale * body::uniform_laplacian(n, scales.unsqueeze(1)).square().mean();
}

at::Tensor total_loss(LossTerms& terms) {
  at::Tensor total;
  for (const char* key : {"image", "lab", "gradient", "mean_offset", "scale", "laplacian_mean", "laplacian_scale"}) {
    const auto it = terms.find(key);
    if (it == terms.end()) continue;
    total = total.defined() ? total + it->second : it->second;
  }
  terms["total"] = total;
  return total;
}

}  // namespace sfgs::train
