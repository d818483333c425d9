// Exporting a trained avatar for other viewers (csrc/train/export.h): the 3DGS .ply and the 32-byte .splat records
// hold the same Gaussians (positions, scales, colours, opacities, unit rotations), the .splat ones largest first;
// other extensions are refused by name.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include "test_avatar_utils.h"
#include "test_files.h"
#include "train/export.h"

namespace sfgs::testing {
namespace {
namespace fs = std::filesystem;

std::vector<unsigned char> file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<unsigned char>((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

struct Exported {
  model::Avatar avatar{nullptr};
  train::ExportedGaussians gaussians;
};

Exported small_export() {
  Exported e;
  e.avatar = model::Avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*e.avatar, 0.05, 51);
  e.avatar->eval();
  e.gaussians = train::exported_gaussians(e.avatar, nullptr, -1);
  return e;
}

TEST(Export, CanonicalGaussiansAreTheAvatarsOwn) {
  Exported e = small_export();
  const train::ExportedGaussians& g = e.gaussians;
  const int64_t n = e.avatar->gaussian_count();
  ASSERT_EQ(g.means.sizes(), at::IntArrayRef({n, 3}));
  at::NoGradGuard no_grad;
  const model::AvatarOutput out = e.avatar->forward(body::SmplxPose::zeros(0), std::nullopt);
  EXPECT_TRUE(at::allclose(g.means, out.canonical_means, 1e-6, 1e-6));
  // Isotropic canonical Gaussians: every axis has the avatar's log-scale.
  EXPECT_TRUE(at::allclose(g.log_scales, out.log_scales.unsqueeze(1).expand({n, 3}), 1e-4, 1e-4));
  EXPECT_LT((g.rotations.norm(2, 1) - 1).abs().max().item<double>(), 1e-5);
}

TEST(Export, PlyAndSplatHoldTheSameGaussians) {
  const Exported e = small_export();
  const train::ExportedGaussians& g = e.gaussians;
  const int64_t n = g.means.size(0);
  const fs::path dir = fs::temp_directory_path() / "sfgs_export_test";
  fs::create_directories(dir);
  const std::string ply = (dir / "avatar.ply").string(), splat = (dir / "avatar.splat").string();
  train::write_ply(g, ply, true);
  train::write_splat(g, splat, true);

  const std::vector<unsigned char> ply_bytes = file_bytes(ply);
  const std::string text(ply_bytes.begin(), ply_bytes.end());
  const size_t header_end = text.find("end_header\n") + std::strlen("end_header\n");
  EXPECT_NE(text.find("element vertex " + std::to_string(n) + "\n"), std::string::npos);
  ASSERT_EQ(ply_bytes.size(), header_end + size_t(n) * 17 * 4);
  float first_row[17];
  std::memcpy(first_row, ply_bytes.data() + header_end, sizeof(first_row));
  for (int k = 0; k < 3; ++k) EXPECT_EQ(first_row[k], g.means[0][k].item<float>());

  const std::vector<unsigned char> records = file_bytes(splat);
  ASSERT_EQ(records.size(), size_t(n) * 32);
  std::vector<double> importance;
  at::Tensor positions = at::empty({n, 3});
  for (int64_t i = 0; i < n; ++i) {
    float values[6];
    std::memcpy(values, records.data() + i * 32, sizeof(values));
    for (int k = 0; k < 3; ++k) positions[i][k] = values[k];
    const unsigned char* colour = records.data() + i * 32 + 24;
    importance.push_back(double(values[3]) * values[4] * values[5] * colour[3] / 255.0);
    double norm = 0;
    for (int k = 0; k < 4; ++k) norm += std::pow((double(records[size_t(i * 32 + 28 + k)]) - 128) / 128, 2);
    EXPECT_NEAR(std::sqrt(norm), 1.0, 0.02) << "record " << i;
  }
  for (int64_t i = 1; i < n; ++i) EXPECT_GE(importance[size_t(i - 1)] * (1 + 1e-5), importance[size_t(i)]) << i;
  // The same positions, in another order.
  std::multiset<std::array<float, 3>> exported, written;
  for (int64_t i = 0; i < n; ++i) {
    exported.insert({g.means[i][0].item<float>(), g.means[i][1].item<float>(), g.means[i][2].item<float>()});
    written.insert({positions[i][0].item<float>(), positions[i][1].item<float>(), positions[i][2].item<float>()});
  }
  EXPECT_TRUE(exported == written);
  expect_error_mentioning(
      [&] {
        train::export_gaussians(const_cast<model::Avatar&>(e.avatar), nullptr, -1, (dir / "a.obj").string(), true);
      },
      "must end in .ply (3DGS) or .splat");
  // The extension's case does not matter (as bench --out's .png).
  train::export_gaussians(const_cast<model::Avatar&>(e.avatar), nullptr, -1, (dir / "upper.PLY").string(), true);
  EXPECT_TRUE(std::filesystem::exists(dir / "upper.PLY"));
}

}  // namespace
}  // namespace sfgs::testing
