// LPIPS with random weights (no files needed): distance properties, finite-difference gradients in float64,
// and the safetensors reader with LPIPS's loader on valid, missing and corrupt files.
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>

#include "metrics/lpips.h"
#include "metrics/safetensors.h"
#include "test_metrics_support.h"

namespace sfgs::testing {
namespace {

using metrics::Lpips;
using metrics::LpipsNet;

TEST(MetricsLpips, DistanceProperties) {
  for (LpipsNet net : {LpipsNet::alex, LpipsNet::squeeze}) {
    const Lpips lpips(net, random_lpips_weights(net, 1));
    const at::Tensor a = random_image(40, 44, 2, at::kFloat), b = random_image(40, 44, 3, at::kFloat);
    EXPECT_EQ(lpips(a, a.clone()).item<double>(), 0.0) << metrics::lpips_net_name(net);
    const double ab = lpips(a, b).item<double>();
    EXPECT_GT(ab, 1e-3);
    EXPECT_NEAR(lpips(b, a).item<double>(), ab, 1e-6 * ab) << "symmetric";
    const at::Tensor layers = lpips.per_layer(a, b);
    EXPECT_EQ(layers.sizes(), at::IntArrayRef({lpips.layer_count()}));
    EXPECT_TRUE((layers > 0).all().item<bool>());
    EXPECT_NEAR(layers.sum().item<double>(), ab, 1e-6 * ab);
    const at::Tensor batch = lpips(at::stack({a, b}), at::stack({b, b}));
    ASSERT_EQ(batch.sizes(), at::IntArrayRef({2}));
    EXPECT_NEAR(batch[0].item<double>(), ab, 1e-5 * ab);
    EXPECT_EQ(batch[1].item<double>(), 0.0);
  }
}

TEST(MetricsLpips, GradientsMatchFiniteDifferences) {
  // Directional derivatives along random directions, for both images, in float64. ReLU and max-pool kinks make
  // LPIPS piecewise smooth; with a 1e-6 step the fixed seeds cross none.
  for (LpipsNet net : {LpipsNet::alex, LpipsNet::squeeze}) {
    const Lpips lpips = Lpips(net, random_lpips_weights(net, 2)).to(at::kCPU, at::kDouble);
    const int64_t side = lpips.min_image_side();
    const at::Tensor a = random_image(side + 1, side + 4, 4), b = random_image(side + 1, side + 4, 5);
    for (bool wrt_prediction : {true, false}) {
      at::Tensor p = a.clone().requires_grad_(wrt_prediction), t = b.clone().requires_grad_(!wrt_prediction);
      const at::Tensor gradient = torch::autograd::grad({lpips(p, t)}, {wrt_prediction ? p : t})[0];
      for (uint64_t seed = 10; seed < 13; ++seed) {
        at::manual_seed(seed);
        const at::Tensor direction = at::randn_like(a);
        const double step = 1e-6;
        const auto at_offset = [&](double s) {
          return (wrt_prediction ? lpips(a + s * direction, b) : lpips(a, b + s * direction)).item<double>();
        };
        const double numeric = (at_offset(step) - at_offset(-step)) / (2 * step);
        const double analytic = (gradient * direction).sum().item<double>();
        EXPECT_NEAR(analytic, numeric, 1e-6 * std::abs(numeric) + 1e-9)
            << metrics::lpips_net_name(net) << " wrt " << (wrt_prediction ? "prediction" : "target");
      }
    }
  }
}

TEST(MetricsLpips, GradientStaysFiniteWhereATapIsAllZero) {
  // A hugely negative last bias switches off every unit of alex's last tap: its norm is 0 everywhere, where a
  // plain sqrt would make autograd produce NaN.
  auto weights = random_lpips_weights(LpipsNet::alex, 3);
  weights["features.10.bias"] = at::full({256}, -1e6, at::kFloat);
  const Lpips lpips(LpipsNet::alex, weights);
  at::Tensor a = random_image(36, 36, 6, at::kFloat).requires_grad_(true);
  const at::Tensor b = random_image(36, 36, 7, at::kFloat);
  const at::Tensor layers = lpips.per_layer(a, b);
  EXPECT_EQ(layers[4].item<double>(), 0.0);
  const at::Tensor gradient = torch::autograd::grad({layers.sum()}, {a})[0];
  EXPECT_TRUE(at::isfinite(gradient).all().item<bool>());
  EXPECT_GT(gradient.abs().max().item<double>(), 0.0);
}

// The training loss differentiates the prediction alone: the target then takes its own pass without autograd, which
// must give the batched pass's value and the prediction the same gradient.
TEST(MetricsLpips, TargetWithoutGradientGivesTheBatchedValueAndGradient) {
  for (LpipsNet net : {LpipsNet::alex, LpipsNet::squeeze}) {
    const Lpips lpips = Lpips(net, random_lpips_weights(net, 5)).to(at::kCPU, at::kDouble);
    const at::Tensor a = random_image(40, 44, 8), b = random_image(40, 44, 9);
    at::Tensor p = a.clone().requires_grad_(true), t = b.clone().requires_grad_(true);
    const at::Tensor batched = lpips(p, t);  // both differentiated: one pass over both images
    const at::Tensor batched_gradient = torch::autograd::grad({batched}, {p})[0];
    at::Tensor q = a.clone().requires_grad_(true);
    const at::Tensor split = lpips(q, b);
    const at::Tensor split_gradient = torch::autograd::grad({split}, {q})[0];
    EXPECT_NEAR(split.item<double>(), batched.item<double>(), 1e-12) << metrics::lpips_net_name(net);
    EXPECT_LT((split_gradient - batched_gradient).abs().max().item<double>(),
              1e-10 * batched_gradient.abs().max().item<double>())
        << metrics::lpips_net_name(net);
  }
}

// A bfloat16 trunk (the CUDA training loss's): the distance and the prediction's gradient come back in the images'
// dtype and stay close to the float32 trunk's (bfloat16's 8-bit mantissa: about a percent on the distance). The
// gradient's direction depends on where the convolutions accumulate: in float32 on tensor cores and on CPUs with
// bfloat16 arithmetic, in bfloat16 on the others (cosine 0.94 on an AMD EPYC without AVX512-BF16).
TEST(MetricsLpips, BFloat16TrunkStaysCloseToFloat) {
  const Lpips lpips(LpipsNet::alex, random_lpips_weights(LpipsNet::alex, 6));
  const Lpips reduced = lpips.with_trunk_dtype(at::kBFloat16);
  const at::Tensor a = random_image(48, 52, 10, at::kFloat), b = random_image(48, 52, 11, at::kFloat);
  at::Tensor p = a.clone().requires_grad_(true), q = a.clone().requires_grad_(true);
  const at::Tensor exact = lpips(p, b), approximate = reduced(q, b);
  EXPECT_EQ(approximate.scalar_type(), at::kFloat);
  EXPECT_NEAR(approximate.item<double>(), exact.item<double>(), 0.03 * exact.item<double>());
  const at::Tensor g = torch::autograd::grad({exact}, {p})[0], h = torch::autograd::grad({approximate}, {q})[0];
  ASSERT_EQ(h.scalar_type(), at::kFloat);
  const double cosine = ((g * h).sum() / (g.norm() * h.norm())).item<double>();
  EXPECT_GT(cosine, 0.9) << "the bfloat16 trunk's gradient points elsewhere";
  EXPECT_EQ(reduced(a, a.clone()).item<double>(), 0.0);
  expect_error([&] { lpips.with_trunk_dtype(at::kInt); },
               {"Lpips::with_trunk_dtype: the trunk needs a floating dtype"});
}

TEST(MetricsLpips, BadImagesAreClearErrors) {
  const Lpips alex(LpipsNet::alex, random_lpips_weights(LpipsNet::alex, 4));
  const at::Tensor small = random_image(30, 40, 1, at::kFloat);
  expect_error([&] { alex(small, small); }, {"lpips (alex): images must be at least 31 x 31 pixels", "[30, 40, 3]"});
  const at::Tensor gray = at::rand({40, 40, 1});
  expect_error([&] { alex(gray, gray); }, {"lpips: images must have 3 channels (last dimension", "[40, 40, 1]"});
  const at::Tensor channels_first = at::rand({2, 3, 40, 40});
  expect_error([&] { alex(channels_first, channels_first); },
               {"channels-last (H, W, C) or (B, H, W, C)", "[2, 3, 40, 40]", ".permute(0, 2, 3, 1)"});
  expect_error([&] { alex(random_image(40, 40, 1, at::kFloat), random_image(40, 41, 1, at::kFloat)); },
               {"lpips: prediction and target must have the same shape"});
}

TEST(MetricsSafetensors, RoundTripOfTensorsAndMetadata) {
  const std::string dir = temporary_folder("round_trip");
  at::manual_seed(5);
  const std::map<std::string, at::Tensor> tensors = {{"b.weight", at::randn({3, 4, 2})}, {"a", at::randn({7})}};
  write_bytes(dir + "/t.safetensors", safetensors_bytes(tensors, {{"note", "[1, 4, 7]"}}));
  const SafetensorsContent content = read_safetensors(dir + "/t.safetensors");
  ASSERT_EQ(content.tensors.size(), 2u);
  for (const auto& [name, t] : tensors) EXPECT_TRUE(at::equal(content.tensors.at(name), t)) << name;
  EXPECT_EQ(content.metadata.at("note"), "[1, 4, 7]");

  // Other dtypes, a scalar and an empty tensor, with 8-byte padding spaces after the JSON as real files have.
  const double d[2] = {1.5, -2.25};
  const int64_t i = -7;
  std::string data(reinterpret_cast<const char*>(d), 16);
  data += std::string(reinterpret_cast<const char*>(&i), 8);
  const nlohmann::json header = {
      {"d", {{"dtype", "F64"}, {"shape", {2}}, {"data_offsets", {0, 16}}}},
      {"i", {{"dtype", "I64"}, {"shape", nlohmann::json::array()}, {"data_offsets", {16, 24}}}},
      {"e", {{"dtype", "U8"}, {"shape", {0, 3}}, {"data_offsets", {24, 24}}}}};
  const std::string text = header.dump() + "     ";
  std::string length(8, '\0');
  for (int k = 0; k < 8; ++k) length[k] = char((uint64_t(text.size()) >> (8 * k)) & 0xff);
  write_bytes(dir + "/typed.safetensors", length + text + data);
  const SafetensorsContent typed = read_safetensors(dir + "/typed.safetensors");
  EXPECT_TRUE(at::equal(typed.tensors.at("d"), at::tensor({1.5, -2.25}, at::kDouble)));
  EXPECT_EQ(typed.tensors.at("i").dim(), 0);
  EXPECT_EQ(typed.tensors.at("i").item<int64_t>(), -7);
  EXPECT_EQ(typed.tensors.at("e").sizes(), at::IntArrayRef({0, 3}));
  EXPECT_EQ(typed.tensors.at("e").scalar_type(), at::kByte);
}

TEST(MetricsSafetensors, MissingAndCorruptFilesNameTheFile) {
  const std::string dir = temporary_folder("corrupt");
  const std::string path = dir + "/w.safetensors";
  expect_error([&] { read_safetensors(dir + "/absent.safetensors"); },
               {"safetensors file '" + dir + "/absent.safetensors' does not exist"});

  const auto expect_corrupt = [&](const std::string& bytes, const std::string& message) {
    write_bytes(path, bytes);
    expect_error([&] { read_safetensors(path); }, {"safetensors file '" + path + "'", message});
  };
  expect_corrupt("abc", "is truncated: 3 bytes, fewer than the 8-byte header length");
  expect_corrupt(std::string("\xff\xff\xff\xff\x00\x00\x00\x00", 8) + "{}", "header length 4294967295 does not fit");
  expect_corrupt(safetensors_bytes(nlohmann::json::array(), ""), "its header is not a JSON object");
  std::string not_json = safetensors_bytes(nlohmann::json::object(), "");
  not_json.replace(8, 2, "{[");
  expect_corrupt(not_json, "its header is not valid JSON");
  const auto entry = [](const std::string& dtype, nlohmann::json shape, nlohmann::json offsets) {
    return nlohmann::json{{"t", {{"dtype", dtype}, {"shape", shape}, {"data_offsets", offsets}}}};
  };
  const std::string four_floats(16, '\0');
  expect_corrupt(safetensors_bytes(entry("F32", {4}, {0, 12}), four_floats), "tensor 't' has data_offsets [0, 12)");
  expect_corrupt(safetensors_bytes(entry("F32", {4}, {0, 16}), four_floats.substr(0, 10)),
                 "is truncated: tensor 't' ends at data byte 16 but the file holds 10 data bytes");
  expect_corrupt(safetensors_bytes(entry("C64", {4}, {0, 16}), four_floats), "unsupported dtype 'C64'");
  expect_corrupt(safetensors_bytes(entry("F32", {-4}, {0, 16}), four_floats), "has an invalid shape [-4]");
  expect_corrupt(safetensors_bytes(nlohmann::json{{"t", 3}}, ""),
                 "must be an object with dtype, shape and data_offsets");
  nlohmann::json overlapping = entry("F32", {2}, {0, 8});
  overlapping["u"] = {{"dtype", "F32"}, {"shape", {2}}, {"data_offsets", {4, 12}}};
  expect_corrupt(safetensors_bytes(overlapping, four_floats), "overlaps the tensor before it");
}

TEST(MetricsLpipsWeights, LoadedFileEqualsTheTensorsItHolds) {
  const std::string dir = temporary_folder("lpips_load");
  const auto weights = random_lpips_weights(LpipsNet::squeeze, 6);
  write_bytes(metrics::lpips_weights_file(LpipsNet::squeeze, dir),
              safetensors_bytes(weights, {{"lpips_version", "0.1"}}));
  const Lpips loaded = Lpips::load(LpipsNet::squeeze, metrics::lpips_weights_file(LpipsNet::squeeze, dir));
  const Lpips direct(LpipsNet::squeeze, weights);
  const at::Tensor a = random_image(24, 30, 8, at::kFloat), b = random_image(24, 30, 9, at::kFloat);
  EXPECT_EQ(loaded(a, b).item<double>(), direct(a, b).item<double>());
}

// Without the environment variables the weights are found beside the source tree, from any working directory (the
// demo's metrics once said "LPIPS unavailable" when run elsewhere).
TEST(MetricsLpipsWeights, TheDefaultFolderDoesNotDependOnTheWorkingDirectory) {
  const std::filesystem::path repository = std::filesystem::path(__FILE__).parent_path().parent_path().parent_path();
  const std::filesystem::path beside = repository / ".." / "shared" / "lpips";
  if (!std::filesystem::is_directory(beside))
    GTEST_SKIP() << "no shared folder beside the repository (" << beside << "): nothing to find";
  std::string saved[2];
  const char* names[2] = {"SFGS_LPIPS_DIR", "SFGS_SHARED_DIR"};
  for (int k = 0; k < 2; ++k) {
    if (const char* v = std::getenv(names[k])) saved[k] = v;
    unsetenv(names[k]);
  }
  const std::filesystem::path before = std::filesystem::current_path();
  std::filesystem::current_path(temporary_folder("lpips_elsewhere"));
  const std::string found = metrics::default_lpips_weights_dir();
  std::filesystem::current_path(before);
  for (int k = 0; k < 2; ++k)
    if (!saved[k].empty()) setenv(names[k], saved[k].c_str(), 1);
  EXPECT_TRUE(std::filesystem::equivalent(found, beside)) << found;
}

TEST(MetricsLpipsWeights, MissingOrWrongWeightsMakeLpipsUnavailable) {
  const std::string dir = temporary_folder("lpips_unavailable");
  const std::string alex_file = metrics::lpips_weights_file(LpipsNet::alex, dir);
  expect_error([&] { Lpips::load(LpipsNet::alex, alex_file); },
               {"LPIPS (alex) unavailable: safetensors file '" + alex_file + "' does not exist"});

  // squeeze's weights under alex's name: the loader notices and names the file.
  write_bytes(alex_file, safetensors_bytes(random_lpips_weights(LpipsNet::squeeze, 7)));
  expect_error([&] { Lpips::load(LpipsNet::alex, alex_file); },
               {"LPIPS (alex) unavailable: weights file '" + alex_file + "'",
                "tensor 'features.0.weight' must be a floating tensor of shape [64, 3, 11, 11], got a Float tensor "
                "of shape [64, 3, 3, 3]"});

  auto missing = random_lpips_weights(LpipsNet::alex, 8);
  missing.erase("lin2.weight");
  write_bytes(alex_file, safetensors_bytes(missing));
  expect_error([&] { Lpips::load(LpipsNet::alex, alex_file); },
               {"LPIPS (alex) unavailable: weights file '" + alex_file + "'", "missing tensor 'lin2.weight'"});

  auto wrong_shape = random_lpips_weights(LpipsNet::alex, 8);
  wrong_shape["features.0.weight"] = at::zeros({64, 3, 11, 10});
  expect_error([&] { Lpips(LpipsNet::alex, wrong_shape); },
               {"tensor 'features.0.weight' must be a floating tensor of shape [64, 3, 11, 11]", "[64, 3, 11, 10]"});

  auto extra = random_lpips_weights(LpipsNet::alex, 9);
  extra["lin5.weight"] = at::zeros({1, 8, 1, 1});
  expect_error([&] { Lpips(LpipsNet::alex, extra); }, {"unexpected tensor 'lin5.weight'"});

  const std::string full = safetensors_bytes(random_lpips_weights(LpipsNet::alex, 10));
  write_bytes(alex_file, full.substr(0, full.size() / 2));
  expect_error([&] { Lpips::load(LpipsNet::alex, alex_file); },
               {"LPIPS (alex) unavailable: safetensors file '" + alex_file + "' is truncated"});
}

}  // namespace
}  // namespace sfgs::testing
