// Agreement with ../shared/lpips/testdata/expected.json (an independent float64 reference; see the README next
// to it): PSNR, SSIM in its three border conventions, and the Python-free LPIPS for both networks, per layer.
// Skipped with a message when the shared folder is absent.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "data/image_io.h"
#include "metrics/evaluation.h"
#include "metrics/image_metrics.h"
#include "metrics/lpips.h"
#include "test_metrics_support.h"

namespace sfgs::testing {
namespace {

using metrics::Lpips;
using metrics::LpipsNet;
using metrics::SsimBorder;

struct ReferencePair {
  std::string name;
  at::Tensor a, b;  // (H, W, 3) float64, exactly u8 / 255
  nlohmann::json expected;
};

class MetricsReference : public ::testing::Test {
 protected:
  void SetUp() override {
    testdata_ = shared_dir() + "/lpips/testdata";
    if (!std::filesystem::exists(testdata_ + "/expected.json")) {
      GTEST_SKIP() << "reference data not found at " << testdata_
                   << "/expected.json (set SFGS_SHARED_DIR to the shared folder to run these tests)";
    }
    std::ifstream file(testdata_ + "/expected.json");
    document_ = nlohmann::json::parse(file);
  }

  std::vector<ReferencePair> pairs() const {
    std::vector<ReferencePair> result;
    for (const auto& entry : document_["pairs"]) {
      // read_image_rgb gives float32 u8 / 255; recover the integers so float64 inputs are exact.
      const auto load = [&](const std::string& file) {
        const at::Tensor v = data::read_image_rgb(testdata_ + "/" + file);
        return at::round(v.to(at::kDouble) * 255.0) / 255.0;
      };
      result.push_back({entry["name"], load(entry["a"]), load(entry["b"]), entry});
    }
    return result;
  }

  double tolerance(const std::string& key) const { return document_["suggested_tolerance"][key].get<double>(); }

  Lpips network(LpipsNet net) const {
    return Lpips::load(net, metrics::lpips_weights_file(net, shared_dir() + "/lpips"));
  }

  std::string testdata_;
  nlohmann::json document_;
};

TEST_F(MetricsReference, PsnrMatches) {
  double worst = 0;
  for (const ReferencePair& p : pairs()) {
    const double value = metrics::psnr(p.a, p.b).item<double>();
    EXPECT_NEAR(value, p.expected["psnr"].get<double>(), tolerance("psnr_abs_float64")) << p.name;
    worst = std::max(worst, std::abs(value - p.expected["psnr"].get<double>()));
  }
  std::cout << "PSNR float64: max |diff| vs expected.json = " << worst << " dB\n";
}

TEST_F(MetricsReference, SsimMatchesInEveryBorderConvention) {
  const std::pair<SsimBorder, const char*> modes[] = {
      {SsimBorder::valid, "ssim_valid"}, {SsimBorder::zero, "ssim_zeropad"}, {SsimBorder::reflect, "ssim_reflect"}};
  for (const auto& [border, key] : modes) {
    double worst64 = 0, worst32 = 0;
    for (const ReferencePair& p : pairs()) {
      const double expected = p.expected[key].get<double>();
      const double value = metrics::ssim(p.a, p.b, border).item<double>();
      EXPECT_NEAR(value, expected, tolerance("ssim_abs_float64")) << p.name << " " << key;
      const double value32 = metrics::ssim(p.a.to(at::kFloat), p.b.to(at::kFloat), border).item<double>();
      EXPECT_NEAR(value32, expected, tolerance("ssim_abs_float32")) << p.name << " " << key << " float32";
      worst64 = std::max(worst64, std::abs(value - expected));
      worst32 = std::max(worst32, std::abs(value32 - expected));
    }
    std::cout << key << ": max |diff| float64 " << worst64 << ", float32 " << worst32 << "\n";
  }
}

TEST_F(MetricsReference, LpipsMatchesForBothNetworks) {
  for (LpipsNet net : {LpipsNet::alex, LpipsNet::squeeze}) {
    const std::string key = std::string("lpips_") + metrics::lpips_net_name(net);
    const Lpips lpips = network(net);
    double worst64 = 0, worst32 = 0, worst_layer = 0;
    for (const ReferencePair& p : pairs()) {
      const double expected = p.expected[key].get<double>();
      const at::Tensor layers = lpips.per_layer(p.a, p.b);
      ASSERT_EQ(layers.size(0), lpips.layer_count());
      for (int64_t l = 0; l < layers.size(0); ++l) {
        const double expected_layer = p.expected[key + "_per_layer"][l].get<double>();
        EXPECT_NEAR(layers[l].item<double>(), expected_layer, tolerance("lpips_abs_float64")) << p.name << " " << l;
        worst_layer = std::max(worst_layer, std::abs(layers[l].item<double>() - expected_layer));
      }
      const double value = layers.sum().item<double>();
      EXPECT_NEAR(value, expected, tolerance("lpips_abs_float64")) << p.name << " " << key;
      const at::Tensor a32 = p.a.to(at::kFloat), b32 = p.b.to(at::kFloat);
      const double value32 = lpips(a32, b32).item<double>();
      EXPECT_NEAR(value32, expected, tolerance("lpips_abs_float32")) << p.name << " " << key << " float32";
      EXPECT_NEAR(lpips(b32, a32).item<double>(), value32, 1e-7) << "LPIPS is symmetric";
      EXPECT_EQ(lpips(a32, a32).item<double>(), 0.0);
      worst64 = std::max(worst64, std::abs(value - expected));
      worst32 = std::max(worst32, std::abs(value32 - expected));
    }
    std::cout << key << ": max |diff| float64 " << worst64 << " (per layer " << worst_layer << "), float32 " << worst32
              << "\n";
  }
}

TEST_F(MetricsReference, BatchesGiveTheSameValuesAsSingleImages) {
  const std::vector<ReferencePair> all = pairs();
  const ReferencePair& p0 = all[0];
  const ReferencePair& p1 = all[1];  // both 64 x 64
  const at::Tensor a = at::stack({p0.a, p1.a}), b = at::stack({p0.b, p1.b});
  const at::Tensor psnr = metrics::psnr(a, b), ssim = metrics::ssim(a, b, SsimBorder::valid);
  const at::Tensor lpips = network(LpipsNet::squeeze)(a, b);
  ASSERT_EQ(psnr.sizes(), at::IntArrayRef({2}));
  for (int i = 0; i < 2; ++i) {
    const ReferencePair& p = i == 0 ? p0 : p1;
    EXPECT_NEAR(psnr[i].item<double>(), p.expected["psnr"].get<double>(), 1e-9);
    EXPECT_NEAR(ssim[i].item<double>(), p.expected["ssim_valid"].get<double>(), 1e-9);
    EXPECT_NEAR(lpips[i].item<double>(), p.expected["lpips_squeeze"].get<double>(), 1e-8);
  }
}

TEST_F(MetricsReference, EvaluatorOnFullImagesReportsTheTorchmetricsNumbers) {
  // composite off = the images as given; SSIM reflect and LPIPS alex (float32) = torchmetrics 1.7.0.
  metrics::EvaluationOptions options;
  options.composite_on_white = false;
  options.lpips_weights_dir = shared_dir() + "/lpips";
  metrics::ImageEvaluator evaluator(options);
  ASSERT_TRUE(evaluator.lpips_available()) << evaluator.lpips_status();
  double psnr_sum = 0;
  const std::vector<ReferencePair> all = pairs();
  for (const ReferencePair& p : all) {
    evaluator.begin_sequence();  // the pairs are unrelated images: no tc-LPIPS between them
    const metrics::FrameMetrics m = evaluator.add_frame(p.a, p.b);
    EXPECT_NEAR(m.psnr, p.expected["psnr"].get<double>(), 1e-9) << p.name;
    EXPECT_NEAR(m.ssim, p.expected["ssim_reflect"].get<double>(), tolerance("ssim_abs_float64")) << p.name;
    ASSERT_TRUE(m.lpips.has_value());
    EXPECT_NEAR(*m.lpips, p.expected["lpips_alex"].get<double>(), tolerance("lpips_abs_float32")) << p.name;
    EXPECT_FALSE(m.tc_lpips.has_value());
    psnr_sum += p.expected["psnr"].get<double>();
  }
  const metrics::EvaluationSummary s = evaluator.summary();
  EXPECT_EQ(s.frames, int64_t(all.size()));
  EXPECT_NEAR(s.psnr, psnr_sum / double(all.size()), 1e-9) << "the mean of per-frame PSNRs";
  EXPECT_EQ(s.consecutive_pairs, 0);
}

}  // namespace
}  // namespace sfgs::testing
