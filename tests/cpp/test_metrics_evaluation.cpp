// The evaluation protocol: compositing on white, the 8-bit round trip, per-frame averaging, tc-LPIPS over
// sequences, and LPIPS reported as unavailable without weights. LPIPS uses random weights (no files needed).
#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "metrics/evaluation.h"
#include "test_metrics_support.h"

namespace sfgs::testing {
namespace {

using metrics::EvaluationOptions;
using metrics::ImageEvaluator;
using metrics::Lpips;
using metrics::LpipsNet;

at::Tensor random_float_image(int64_t h, int64_t w, uint64_t seed) {
  at::manual_seed(seed);
  return at::rand({h, w, 3}, at::kFloat);
}

Lpips random_squeeze() { return Lpips(LpipsNet::squeeze, random_lpips_weights(LpipsNet::squeeze, 21)); }

TEST(MetricsComposite, WhiteOutsideTheMask) {
  const at::Tensor image = random_float_image(6, 7, 1);
  at::Tensor mask = at::zeros({6, 7}, at::kBool);
  mask.slice(0, 1, 4).fill_(true);
  const at::Tensor out = metrics::composite_on_white(image, mask);
  EXPECT_TRUE(at::equal(out.slice(0, 1, 4), image.slice(0, 1, 4)));
  EXPECT_TRUE((out.slice(0, 4) == 1.0f).all().item<bool>());
  EXPECT_TRUE((out.slice(0, 0, 1) == 1.0f).all().item<bool>());
  // A soft mask blends: 0.25 of the image plus 0.75 white.
  const at::Tensor soft = metrics::composite_on_white(image, at::full({6, 7, 1}, 0.25, at::kFloat));
  EXPECT_TRUE(at::allclose(soft, image * 0.25 + 0.75));
  // A per-channel mask (NeuMan's masks are read as 3-channel images).
  at::Tensor per_channel = at::ones({6, 7, 3}, at::kFloat);
  per_channel.select(2, 1).zero_();
  const at::Tensor channel_out = metrics::composite_on_white(image, per_channel);
  EXPECT_TRUE((channel_out.select(2, 1) == 1.0f).all().item<bool>());
  EXPECT_TRUE(at::equal(channel_out.select(2, 0), image.select(2, 0)));
  expect_error(
      [&] {
        metrics::composite_on_white(image, at::ones({6, 8}));
      },
      {"mask must cover the image's 6 x 7 pixels with 1 or 3 channels", "[6, 8]"});
}

TEST(MetricsRoundTrip, RoundsHalfToEvenAndSaturatesAsOpenCv) {
  // (k + 0.5) / 255 * 255 is exactly k + 0.5 for these k, so the tie rule decides: 0.5 -> 0, 1.5 -> 2, 2.5 -> 2,
  // 3.5 -> 4 (what cv2.imwrite(img * 255) stores: OpenCV 4.6 measured on this machine).
  for (at::ScalarType dtype : {at::kFloat, at::kDouble}) {
    const at::Tensor halves = (at::arange(4, dtype) + 0.5) / 255.0;
    ASSERT_TRUE(at::equal(halves * 255.0, at::arange(4, dtype) + 0.5)) << "precondition: exact products";
    EXPECT_TRUE(at::equal(metrics::eight_bit_round_trip(halves), at::tensor({0.0, 2.0, 2.0, 4.0}, dtype) / 255.0));
  }
  const at::Tensor odd = at::tensor({-0.1, 1.2, std::nan(""), 0.3 / 255.0, 100.7 / 255.0}, at::kDouble);
  EXPECT_TRUE(
      at::equal(metrics::eight_bit_round_trip(odd), at::tensor({0.0, 255.0, 0.0, 0.0, 101.0}, at::kDouble) / 255.0));
  // 8-bit values survive unchanged.
  const at::Tensor levels = at::arange(256, at::kFloat) / 255.0f;
  EXPECT_TRUE(at::equal(metrics::eight_bit_round_trip(levels), levels));
}

TEST(MetricsEvaluator, DifferencesOutsideTheGroundTruthMaskDoNotCount) {
  const at::Tensor target = random_float_image(32, 40, 2);
  at::Tensor mask = at::zeros({32, 40}, at::kFloat);
  mask.slice(0, 8, 24).slice(1, 10, 30).fill_(1.0f);
  const at::Tensor prediction = at::where(mask.unsqueeze(-1) > 0, target, random_float_image(32, 40, 3));
  ImageEvaluator evaluator(EvaluationOptions{}, random_squeeze());
  const metrics::FrameMetrics m = evaluator.add_frame(prediction, target, mask);
  EXPECT_TRUE(std::isinf(m.psnr) && m.psnr > 0);
  EXPECT_NEAR(m.ssim, 1.0, 1e-12);
  ASSERT_TRUE(m.lpips.has_value());
  EXPECT_EQ(*m.lpips, 0.0);

  EvaluationOptions full;
  full.composite_on_white = false;
  ImageEvaluator full_image(full, random_squeeze());
  const metrics::FrameMetrics f = full_image.add_frame(prediction, target);
  EXPECT_LT(f.psnr, 20.0);
  EXPECT_GT(*f.lpips, 1e-3);
  expect_error([&] { evaluator.add_frame(prediction, target); }, {"a ground-truth mask is required"});
}

TEST(MetricsEvaluator, EightBitRoundTripOfThePrediction) {
  at::manual_seed(4);
  const at::Tensor target = at::randint(0, 255, {24, 20, 3}, at::kFloat) / 255.0f;  // as read from a PNG
  const at::Tensor prediction = target + 0.3f / 255.0f;                             // rounds back to target
  const at::Tensor mask = at::ones({24, 20});
  EvaluationOptions options;
  options.eight_bit_round_trip = true;
  ImageEvaluator rounded(options, random_squeeze());
  const double rounded_psnr = rounded.add_frame(prediction, target, mask).psnr;
  EXPECT_TRUE(std::isinf(rounded_psnr)) << rounded_psnr;
  ImageEvaluator exact(EvaluationOptions{}, random_squeeze());
  EXPECT_NEAR(exact.add_frame(prediction, target, mask).psnr, -20.0 * std::log10(0.3 / 255.0), 1e-3);
}

TEST(MetricsEvaluator, AveragesPerFrameValues) {
  // PSNRs of 20 and 40 dB average to 30 (the PSNR of the mean MSE would be 22.97 dB).
  EvaluationOptions options;
  options.composite_on_white = false;
  options.ssim_border = metrics::SsimBorder::valid;
  ImageEvaluator evaluator(options, random_squeeze());
  const at::Tensor target = (random_float_image(20, 24, 5) * 0.6 + 0.2).to(at::kDouble);
  at::manual_seed(6);
  const at::Tensor signs = at::where(at::rand_like(target) < 0.5, -at::ones_like(target), at::ones_like(target));
  double ssim_sum = 0;
  for (double delta : {0.1, 0.01}) {
    const at::Tensor prediction = target + delta * signs;
    const metrics::FrameMetrics m = evaluator.add_frame(prediction, target);
    EXPECT_NEAR(m.psnr, -20.0 * std::log10(delta), 1e-10);
    ssim_sum += metrics::ssim(prediction, target, metrics::SsimBorder::valid).item<double>();
  }
  const metrics::EvaluationSummary s = evaluator.summary();
  EXPECT_EQ(s.frames, 2);
  EXPECT_NEAR(s.psnr, 30.0, 1e-10);
  EXPECT_NEAR(s.ssim, ssim_sum / 2, 1e-12);
}

TEST(MetricsEvaluator, TcLpipsComparesConsecutiveFramesWithTheGroundTruth) {
  const Lpips lpips = random_squeeze();
  EvaluationOptions options;
  options.composite_on_white = false;
  ImageEvaluator evaluator(options, lpips);
  std::vector<at::Tensor> predictions, targets;
  for (uint64_t t = 0; t < 3; ++t) {
    predictions.push_back(random_float_image(24, 28, 10 + t));
    targets.push_back(random_float_image(24, 28, 20 + t));
  }
  const metrics::FrameMetrics first = evaluator.add_frame(predictions[0], targets[0]);
  EXPECT_FALSE(first.tc_lpips.has_value()) << "the first frame of a sequence has no predecessor";
  double tc_sum = 0, consecutive_sum = 0;
  for (int t = 1; t < 3; ++t) {
    const metrics::FrameMetrics m = evaluator.add_frame(predictions[t], targets[t]);
    const double moved_prediction = lpips(predictions[t], predictions[t - 1]).item<double>();
    const double moved_target = lpips(targets[t], targets[t - 1]).item<double>();
    ASSERT_TRUE(m.tc_lpips.has_value() && m.consecutive_lpips.has_value());
    EXPECT_NEAR(*m.consecutive_lpips, moved_prediction, 1e-6);
    EXPECT_NEAR(*m.tc_lpips, std::abs(moved_prediction - moved_target), 1e-6);
    EXPECT_NEAR(*m.lpips, lpips(predictions[t], targets[t]).item<double>(), 1e-6);
    tc_sum += *m.tc_lpips;
    consecutive_sum += *m.consecutive_lpips;
  }
  evaluator.begin_sequence();
  EXPECT_FALSE(evaluator.add_frame(predictions[0], targets[0]).tc_lpips.has_value()) << "no pair across sequences";
  const metrics::EvaluationSummary s = evaluator.summary();
  EXPECT_EQ(s.frames, 4);
  EXPECT_EQ(s.consecutive_pairs, 2);
  EXPECT_NEAR(*s.tc_lpips, tc_sum / 2, 1e-12);
  EXPECT_NEAR(*s.consecutive_lpips, consecutive_sum / 2, 1e-12);

  // A prediction that changes exactly as the ground truth does has no temporal error, however far from it.
  ImageEvaluator same_motion(options, lpips);
  same_motion.add_frame(predictions[0], predictions[1]);
  const metrics::FrameMetrics swapped = same_motion.add_frame(predictions[1], predictions[0]);
  EXPECT_NEAR(*swapped.tc_lpips, 0.0, 1e-6);
  EXPECT_GT(*swapped.consecutive_lpips, 1e-3);
}

TEST(MetricsEvaluator, MissingWeightsReportLpipsUnavailableNeverZero) {
  EvaluationOptions options;
  options.lpips_weights_dir = temporary_folder("no_weights");
  ImageEvaluator evaluator(options);
  EXPECT_FALSE(evaluator.lpips_available());
  EXPECT_NE(evaluator.lpips_status().find("LPIPS (alex) unavailable: safetensors file '" + options.lpips_weights_dir +
                                          "/lpips_alex.safetensors' does not exist"),
            std::string::npos)
      << evaluator.lpips_status();
  const at::Tensor image = random_float_image(20, 20, 7);
  const metrics::FrameMetrics m = evaluator.add_frame(image, random_float_image(20, 20, 8), at::ones({20, 20}));
  EXPECT_FALSE(m.lpips.has_value());
  EXPECT_TRUE(std::isfinite(m.psnr));
  const metrics::EvaluationSummary s = evaluator.summary();
  EXPECT_FALSE(s.lpips.has_value());
  const std::string text = metrics::to_string(s);
  EXPECT_NE(text.find("LPIPS (alex) unavailable"), std::string::npos) << text;
  EXPECT_EQ(text.find("LPIPS 0"), std::string::npos) << text;
}

TEST(MetricsEvaluator, SummaryText) {
  metrics::EvaluationSummary s;
  s.frames = 3;
  s.psnr = 30.12346;
  s.ssim = 0.9812346;
  s.lpips = 0.0178904;
  s.consecutive_pairs = 2;
  s.consecutive_lpips = 0.05;
  s.tc_lpips = 0.0012341;
  EXPECT_EQ(metrics::to_string(s),
            "frames 3  PSNR 30.1235  SSIM 0.981235  LPIPS 0.017890  tc-LPIPS 0.001234 (2 pairs; consecutive-frame "
            "LPIPS 0.050000)");
}

}  // namespace
}  // namespace sfgs::testing
