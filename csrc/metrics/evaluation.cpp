// The evaluation protocol on top of the image metrics and LPIPS.
#include "metrics/evaluation.h"

#include <cmath>
#include <cstdio>
#include <utility>

#include <ATen/ATen.h>

#include "common/constants.h"
#include "metrics/image_layout.h"

namespace sfgs::metrics {
namespace {

std::string format_number(const char* format, double value) {
  char text[64];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

}  // namespace

at::Tensor composite_on_white(const at::Tensor& image, const at::Tensor& mask) {
  TORCH_CHECK(image.defined() && image.dim() == 3 && at::isFloatingType(image.scalar_type()),
              "composite_on_white: image must be a floating (H, W, C) tensor, got ", describe(image));
  TORCH_CHECK(mask.defined() && (mask.dim() == 2 || mask.dim() == 3) &&
                  (mask.scalar_type() == at::kBool || at::isFloatingType(mask.scalar_type())),
              "composite_on_white: mask must be a bool or floating (H, W), (H, W, 1) or (H, W, C) tensor, got ",
              describe(mask));
  const at::Tensor m = mask.dim() == 2 ? mask.unsqueeze(-1) : mask;
  TORCH_CHECK(m.size(0) == image.size(0) && m.size(1) == image.size(1) &&
                  (m.size(2) == 1 || m.size(2) == image.size(2)) && m.device() == image.device(),
              "composite_on_white: mask must cover the image's ", image.size(0), " x ", image.size(1),
              " pixels with 1 or ", image.size(2), " channels on its device, got ", describe(mask), " for ",
              describe(image));
  const at::Tensor weight = m.to(image.scalar_type());
  return image * weight + (1.0 - weight);
}

at::Tensor eight_bit_round_trip(const at::Tensor& image) {
  TORCH_CHECK(image.defined() && at::isFloatingType(image.scalar_type()),
              "eight_bit_round_trip: image must be a floating tensor, got ", describe(image));
  // The product in the image's own dtype, as numpy forms img * 255 before OpenCV converts it.
  const at::Tensor scaled = at::nan_to_num(image.detach() * kEightBitMax, 0.0).clamp(0.0, kEightBitMax);
  return at::round(scaled) / kEightBitMax;
}

std::string to_string(const EvaluationSummary& s) {
  std::string text = "frames " + std::to_string(s.frames) + "  PSNR " + format_number("%.4f", s.psnr) + "  SSIM " +
                     format_number("%.6f", s.ssim);
  if (!s.lpips) return text + "  " + s.lpips_status;
  text += "  LPIPS " + format_number("%.6f", *s.lpips);
  if (s.tc_lpips) {
    text += "  tc-LPIPS " + format_number("%.6f", *s.tc_lpips) + " (" + std::to_string(s.consecutive_pairs) +
            " pairs; consecutive-frame LPIPS " + format_number("%.6f", *s.consecutive_lpips) + ")";
  }
  return text;
}

ImageEvaluator::ImageEvaluator(EvaluationOptions options) : options_(std::move(options)) {
  const std::string file = lpips_weights_file(options_.lpips_net, options_.lpips_weights_dir);
  try {
    lpips_.emplace(Lpips::load(options_.lpips_net, file));
    lpips_status_ = std::string(lpips_net_name(options_.lpips_net)) + " (" + file + ")";
  } catch (const c10::Error& e) {
    lpips_status_ = e.what_without_backtrace();
  }
}

ImageEvaluator::ImageEvaluator(EvaluationOptions options, Lpips lpips)
    : options_(std::move(options)),
      lpips_(std::move(lpips)),
      lpips_status_(std::string(lpips_net_name(lpips_->net())) + " (given)") {}

void ImageEvaluator::begin_sequence() {
  previous_prediction_.reset();
  previous_target_.reset();
}

std::pair<at::Tensor, at::Tensor> ImageEvaluator::compared_images(const at::Tensor& prediction,
                                                                  const at::Tensor& target,
                                                                  const at::Tensor& mask) const {
  TORCH_CHECK(!options_.composite_on_white || mask.defined(),
              "ImageEvaluator::add_frame: a ground-truth mask is required when composite_on_white is set");
  at::Tensor p = prediction.detach(), t = target.detach();
  if (options_.eight_bit_round_trip) p = eight_bit_round_trip(p);
  if (options_.composite_on_white) {
    p = composite_on_white(p, mask.detach());
    t = composite_on_white(t, mask.detach());
  }
  return {p, t};
}

FrameMetrics ImageEvaluator::add_frame(const at::Tensor& prediction, const at::Tensor& target, const at::Tensor& mask) {
  detail::check_image_pair("ImageEvaluator::add_frame", prediction, target, 3);
  TORCH_CHECK(prediction.dim() == 3, "ImageEvaluator::add_frame: one frame (H, W, 3) at a time, got ",
              describe(prediction));
  const auto [p, t] = compared_images(prediction, target, mask);

  FrameMetrics frame;
  // SSIM in float64: in float32 the cancellation in E[x^2] - mu^2 plus the reflect mode's variance clamp pull
  // flat regions of identical images down to 0.9993 for some grey levels.
  const at::Tensor p64 = p.to(at::kDouble), t64 = t.to(at::kDouble);
  frame.psnr = psnr(p64, t64).item<double>();
  frame.ssim = ssim(p64, t64, options_.ssim_border).item<double>();
  if (lpips_) {
    if (lpips_->device() != p.device()) lpips_ = lpips_->to(p.device(), at::kFloat);
    const LpipsFeatures both = lpips_->features(at::stack({p, t}).to(at::kFloat));
    LpipsFeatures fp, ft;
    for (const at::Tensor& tap : both.taps) {
      fp.taps.push_back(tap.narrow(0, 0, 1));
      ft.taps.push_back(tap.narrow(0, 1, 1));
    }
    frame.lpips = lpips_->per_layer_distance(fp, ft).sum().item<double>();
    if (previous_prediction_) {
      const double moved_prediction = lpips_->per_layer_distance(fp, *previous_prediction_).sum().item<double>();
      const double moved_target = lpips_->per_layer_distance(ft, *previous_target_).sum().item<double>();
      frame.consecutive_lpips = moved_prediction;
      frame.tc_lpips = std::abs(moved_prediction - moved_target);
      consecutive_sum_ += moved_prediction;
      tc_sum_ += *frame.tc_lpips;
      ++pairs_;
    }
    previous_prediction_ = std::move(fp);
    previous_target_ = std::move(ft);
    lpips_sum_ += *frame.lpips;
  }
  ++frames_;
  psnr_sum_ += frame.psnr;
  ssim_sum_ += frame.ssim;
  return frame;
}

EvaluationSummary ImageEvaluator::summary() const {
  EvaluationSummary s;
  s.frames = frames_;
  s.consecutive_pairs = pairs_;
  s.lpips_status = lpips_status_;
  const double nan = std::nan("");
  s.psnr = frames_ > 0 ? psnr_sum_ / double(frames_) : nan;
  s.ssim = frames_ > 0 ? ssim_sum_ / double(frames_) : nan;
  if (lpips_) {
    s.lpips = frames_ > 0 ? lpips_sum_ / double(frames_) : nan;
    if (pairs_ > 0) {
      s.consecutive_lpips = consecutive_sum_ / double(pairs_);
      s.tc_lpips = tc_sum_ / double(pairs_);
    }
  }
  return s;
}

}  // namespace sfgs::metrics
