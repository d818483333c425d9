#pragma once
// The ExAvatar / SFGS image evaluation protocol: per-frame PSNR, SSIM and LPIPS (AlexNet) on full images with
// prediction and ground truth composited on white outside the ground-truth mask, averaged over frames; an
// optional 8-bit round trip of the prediction as the published numbers had; tc-LPIPS over consecutive frames.
// See docs/metrics.md for the exact definitions.
#include <cstdint>
#include <optional>
#include <string>
#include <utility>

#include <ATen/core/Tensor.h>

#include "metrics/image_metrics.h"
#include "metrics/lpips.h"

namespace sfgs::metrics {

// image * mask + (1 - mask): white outside the mask. image (H, W, C); mask (H, W), (H, W, 1) or (H, W, C),
// bool or floating in [0, 1]. Differentiable w.r.t. the image.
at::Tensor composite_on_white(const at::Tensor& image, const at::Tensor& mask);

// What cv2.imwrite(path, image * 255) followed by cv2.imread(path) / 255 does to a floating image: OpenCV
// converts to 8 bits by rounding half to even and saturating to [0, 255] (NaN becomes 0). Not differentiable.
at::Tensor eight_bit_round_trip(const at::Tensor& image);

struct EvaluationOptions {
  // Composite prediction and ground truth on white outside the ground-truth mask (ExAvatar/SFGS human-only
  // numbers). false: compare the full images as given (NeuMan's --include_bkg).
  bool composite_on_white = true;
  // Round-trip the prediction through 8 bits before compositing, as the references evaluate the PNGs they wrote.
  bool eight_bit_round_trip = false;
  // torchmetrics >= 1.4.2, as pinned by ExAvatar (1.7.0).
  SsimBorder ssim_border = SsimBorder::reflect;
  LpipsNet lpips_net = LpipsNet::alex;
  std::string lpips_weights_dir = default_lpips_weights_dir();
};

struct FrameMetrics {
  double psnr = 0, ssim = 0;
  std::optional<double> lpips;  // nullopt when LPIPS is unavailable
  // Only for a frame with a predecessor in its sequence (and LPIPS available):
  std::optional<double> consecutive_lpips;  // LPIPS(prediction_t, prediction_{t-1})
  std::optional<double> tc_lpips;           // |LPIPS(pred_t, pred_{t-1}) - LPIPS(target_t, target_{t-1})|
};

struct EvaluationSummary {
  int64_t frames = 0;
  double psnr = 0, ssim = 0;  // means of the per-frame values (a frame identical to its target makes PSNR +inf)
  std::optional<double> lpips;
  int64_t consecutive_pairs = 0;
  std::optional<double> consecutive_lpips, tc_lpips;  // means over the consecutive pairs
  std::string lpips_status;                           // the network and file, or why LPIPS is unavailable
};

// "frames 3  PSNR 30.1234  SSIM 0.981234  LPIPS 0.017890  tc-LPIPS 0.001234 (2 pairs)", with
// "LPIPS (alex) unavailable: <reason>" in place of the LPIPS numbers when there is no network.
std::string to_string(const EvaluationSummary& summary);

// Accumulates the protocol's metrics frame by frame on the images' device: PSNR and SSIM in float64, LPIPS in
// float32 (as the references' torchmetrics does).
class ImageEvaluator {
 public:
  // Loads LPIPS from options.lpips_weights_dir. Missing or broken weights do not stop the evaluation: LPIPS is
  // then reported unavailable with the reason (lpips_status), never as 0.
  explicit ImageEvaluator(EvaluationOptions options = {});
  // Uses the given network (options.lpips_net and lpips_weights_dir are ignored).
  ImageEvaluator(EvaluationOptions options, Lpips lpips);

  bool lpips_available() const { return lpips_.has_value(); }
  const std::string& lpips_status() const { return lpips_status_; }

  // prediction and target (H, W, 3) in [0, 1]; mask as composite_on_white's, required when compositing.
  FrameMetrics add_frame(const at::Tensor& prediction, const at::Tensor& target, const at::Tensor& mask = {});
  // The pair as add_frame compares it (detached): the prediction round-tripped through 8 bits and both composited
  // on white, as the options say. For measures of parts of a frame (train/region_metrics.h).
  std::pair<at::Tensor, at::Tensor> compared_images(const at::Tensor& prediction, const at::Tensor& target,
                                                    const at::Tensor& mask = {}) const;
  // The next frame starts a new sequence (another video or take): tc-LPIPS never pairs frames across sequences.
  void begin_sequence();
  EvaluationSummary summary() const;

 private:
  EvaluationOptions options_;
  std::optional<Lpips> lpips_;
  std::string lpips_status_;
  std::optional<LpipsFeatures> previous_prediction_, previous_target_;
  int64_t frames_ = 0, pairs_ = 0;
  double psnr_sum_ = 0, ssim_sum_ = 0, lpips_sum_ = 0, consecutive_sum_ = 0, tc_sum_ = 0;
};

}  // namespace sfgs::metrics
