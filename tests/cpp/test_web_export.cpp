// The web viewer's export (csrc/train/web_export.h): the folder appears whole or not at all and replaces only an
// earlier export; read back and posed with the viewer's arithmetic (web/pose_player.js, repeated here in LibTorch),
// it reproduces the avatar's frames, and each of the viewer's approximations is measured on its own by rendering
// with sfgs::render (the numbers docs/web_viewer.md quotes; the browser's own rasterisation is tested by
// tests/python/test_web_viewer.py).
#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "body/mesh.h"
#include "metrics/image_metrics.h"
#include "model/shading.h"
#include "test_avatar_utils.h"
#include "test_files.h"
#include "train/web_export.h"
#include "train/constants.h"

namespace sfgs::testing {
namespace {
namespace fs = std::filesystem;

constexpr int64_t kFrames = 3;
constexpr int64_t kWidth = 160, kHeight = 240;

std::string file_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::vector<unsigned char> decode_base64(const std::string& text) {
  const std::string alphabet = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::vector<unsigned char> bytes;
  uint32_t bits = 0;
  int count = 0;
  for (const char c : text) {
    if (c == '=') break;
    bits = (bits << 6) | uint32_t(alphabet.find(c));
    count += 6;
    if (count >= 8) {
      count -= 8;
      bytes.push_back(static_cast<unsigned char>((bits >> count) & 0xff));
    }
  }
  return bytes;
}

// The folder as the page reads it: the manifest and every data script's bytes.
struct ViewerFolder {
  nlohmann::json manifest;
  std::vector<std::vector<unsigned char>> files;

  explicit ViewerFolder(const std::string& folder) {
    const std::string script = file_text(folder + "/data/manifest.js");
    const std::string prefix = "var sfgsExport = ";
    const size_t end = script.find(";\nvar sfgsData = [];");
    if (script.rfind(prefix, 0) != 0 || end == std::string::npos) throw std::runtime_error("unexpected manifest.js");
    manifest = nlohmann::json::parse(script.substr(prefix.size(), end - prefix.size()));
    for (size_t k = 0; k < manifest["files"].size(); ++k) {
      const std::string data = file_text(folder + "/" + manifest["files"][k].get<std::string>());
      const std::string head = "sfgsData[" + std::to_string(k) + "] = \"";
      if (data.rfind(head, 0) != 0) throw std::runtime_error("unexpected data script " + std::to_string(k));
      files.push_back(decode_base64(data.substr(head.size(), data.rfind('"') - head.size())));
    }
  }

  // A buffer as a float64 tensor of its values.
  at::Tensor buffer(const nlohmann::json& entry) const {
    const std::string type = entry["type"];
    const at::ScalarType dtype = type == "float32"  ? at::kFloat
                                 : type == "uint32" ? at::kInt
                                 : type == "int8"   ? at::kChar
                                                    : at::kByte;
    const auto& bytes = files[entry["file"].get<size_t>()];
    const int64_t length = entry["length"];
    const at::Tensor t = at::empty({length}, at::TensorOptions().dtype(dtype));
    std::memcpy(t.data_ptr(), bytes.data() + entry["offset"].get<size_t>(), size_t(length * t.element_size()));
    return t.to(at::kDouble);
  }
};

// Frame f as web/pose_player.js computes it, and the parts that go into it.
struct ViewerFrame {
  at::Tensor means, covariances, colours, opacities;  // what the page draws
  at::Tensor albedo, shading, normals;                // the decoded albedo, the skinned mesh's normals, their shading
};

ViewerFrame viewer_frame(const ViewerFolder& v, int64_t f) {
  const nlohmann::json& m = v.manifest;
  const nlohmann::json& frame = m["frame_buffers"][f];
  const int64_t n = m["gaussians"], k = m["influences"];
  const at::Tensor joints = v.buffer(m["buffers"]["joints"]).to(at::kLong).view({n, k});
  const at::Tensor weights = v.buffer(m["buffers"]["weights"]).view({n, k}) / m["weight_total"].get<double>();
  const at::Tensor transforms = v.buffer(frame["transforms"]).view({-1, 12});
  const at::Tensor a =
      (transforms.index_select(0, joints.flatten()).view({n, k, 12}) * weights.unsqueeze(2)).sum(1).view({n, 3, 4});
  const at::Tensor linear = a.slice(2, 0, 3);
  const at::Tensor rest = v.buffer(m["buffers"]["means"]).view({n, 3});
  ViewerFrame out;
  out.means = at::matmul(linear, rest.unsqueeze(2)).squeeze(2) + a.select(2, 3) +
              v.buffer(frame["mean_offsets"]).view({n, 3}) * frame["mean_step"].get<double>();
  const at::Tensor log_scales = v.buffer(m["buffers"]["log_scales"]) +
                                v.buffer(frame["log_scale_offsets"]) * frame["log_scale_step"].get<double>();
  const at::Tensor gram = at::matmul(linear, linear.transpose(1, 2)) * (2 * log_scales).exp().view({n, 1, 1});
  out.covariances =
      at::stack({gram.select(1, 0).select(1, 0), gram.select(1, 0).select(1, 1), gram.select(1, 0).select(1, 2),
                 gram.select(1, 1).select(1, 1), gram.select(1, 1).select(1, 2), gram.select(1, 2).select(1, 2)},
                1);
  const at::Tensor mesh = v.buffer(m["buffers"]["mesh"]).view({n, 3});
  const at::Tensor posed_mesh = at::matmul(linear, mesh.unsqueeze(2)).squeeze(2) + a.select(2, 3);
  out.normals = body::vertex_normals(posed_mesh, v.buffer(m["buffers"]["faces"]).to(at::kLong).view({-1, 3}));
  const double levels = m["colour_levels"];
  out.albedo = v.buffer(m["buffers"]["albedo"]).view({n, 3}) / levels;
  const at::Tensor coefficients = at::tensor(m["shading"].get<std::vector<double>>(), at::kDouble).view({9, 3});
  out.shading = model::ShadingImpl::basis(out.normals).matmul(coefficients).clamp_min(0);
  out.colours = out.albedo * out.shading;
  out.opacities = v.buffer(m["buffers"]["opacities"]) / levels;
  return out;
}

// The camera of the export and of the renders compared here: 2.8 m in front of the body, looking at it (as
// `sfgs render --camera fixed` places its camera).
train::WebCamera front_camera(const model::AvatarOutput& first) {
  const at::Tensor points = first.means.detach().to(at::kDouble);
  const at::Tensor centre = (std::get<0>(points.min(0)) + std::get<0>(points.max(0))) / 2;
  train::WebCamera c;
  c.target = {centre[0].item<double>(), centre[1].item<double>(), centre[2].item<double>()};
  c.camera = Camera::looking_forward(1.2 * kHeight, kWidth, kHeight);
  // Rows right (1, 0, 0), down (0, -1, 0), forward (0, 0, -1); the eye at target + (0, 0, 2.8).
  c.camera.world_to_camera = {1, 0, 0, -c.target[0], 0, -1, 0, c.target[1], 0, 0, -1, c.target[2] + 2.8, 0, 0, 0, 1};
  return c;
}

struct WebFixture {
  model::Avatar avatar{nullptr};
  train::WebMotion motion;
  train::WebCamera camera;

  WebFixture() {
    avatar = model::Avatar(procedural_avatar_body(), subject_betas(), small_config());
    randomise_parameters(*avatar, 0.05, 15);
    avatar->eval();
    motion.name = "test";
    motion.frames = kFrames;
    motion.frames_per_second = 24;
    motion.pose = [this](int64_t i) { return avatar->forward(test_pose(40 + i, 0.6, true), std::nullopt); };
    at::NoGradGuard no_grad;
    camera = front_camera(motion.pose(0));
  }
};

at::Tensor render_image(const at::Tensor& means, const at::Tensor& covariances, const at::Tensor& colours,
                        const at::Tensor& opacities, const Camera& camera) {
  Gaussians g;
  g.means = means.to(at::kFloat);
  g.covariances = covariances.to(at::kFloat);
  g.features = colours.to(at::kFloat);
  g.opacities = opacities.to(at::kFloat);
  return render(g, at::ones({3}), camera).image;
}

double psnr_of(const at::Tensor& image, const at::Tensor& reference) {
  return metrics::psnr(image.clamp(0, 1), reference.clamp(0, 1)).item<double>();
}

TEST(WebExport, ViewerReproducesTheAvatarsFramesAndEachApproximationIsMeasured) {
  WebFixture fx;
  TempFolder tmp;
  const std::string folder = tmp / "web";
  const train::WebExportSummary summary = train::export_web_viewer(fx.avatar, fx.motion, fx.camera, folder, false);
  EXPECT_EQ(summary.gaussians, fx.avatar->gaussian_count());
  EXPECT_EQ(summary.frames, kFrames);
  EXPECT_EQ(summary.influences, kWebViewerInfluences);
  const ViewerFolder viewer(folder);
  const int64_t n = summary.gaussians;
  // Each Gaussian's 8-bit weights sum to 255 exactly: the viewer needs no renormalisation.
  const at::Tensor weight_sums = viewer.buffer(viewer.manifest["buffers"]["weights"]).view({n, -1}).sum(1);
  EXPECT_TRUE(at::all(weight_sums == 255).item<bool>());

  at::NoGradGuard no_grad;
  for (int64_t f = 0; f < kFrames; ++f) {
    const model::AvatarOutput exact = fx.motion.pose(f);
    const ViewerFrame web = viewer_frame(viewer, f);
    const nlohmann::json& frame = viewer.manifest["frame_buffers"][f];
    // Means: exact up to the offsets' 8-bit rounding (half a step per axis).
    const double step = frame["mean_step"];
    EXPECT_LE((web.means - exact.means.to(at::kDouble)).abs().max().item<double>(), 0.5 * step + 1e-6);
    const auto render_with = [&](const at::Tensor& means, const at::Tensor& covariances, const at::Tensor& colours) {
      return render_image(means, covariances, colours, exact.opacities, fx.camera.camera);
    };
    const at::Tensor reference = render_with(exact.means, exact.covariances, exact.colours);
    const double all = psnr_of(render_with(web.means, web.covariances, web.colours), reference);
    const double means = psnr_of(render_with(web.means, exact.covariances, exact.colours), reference);
    const double covariances = psnr_of(render_with(exact.means, web.covariances, exact.colours), reference);
    const double albedo = psnr_of(render_with(exact.means, exact.covariances, web.albedo * exact.shading), reference);
    const double normals =
        psnr_of(render_with(exact.means, exact.covariances, exact.albedo.to(at::kDouble) * web.shading), reference);
    const double normal_degrees =
        at::rad2deg(at::acos((web.normals * exact.posed_normals.to(at::kDouble)).sum(1).clamp(-1, 1)))
            .max()
            .item<double>();
    std::printf(
        "web viewer frame %lld: PSNR against the avatar's render %.1f dB; each approximation alone: mean "
        "offsets (8-bit) %.1f, covariances (4 joints, 8-bit weights and log-scale offsets) %.1f, albedo "
        "(8-bit) %.1f, normals (of the skinned rest mesh; largest error %.1f degrees) %.1f dB\n",
        (long long)f, all, means, covariances, albedo, normal_degrees, normals);
    EXPECT_GT(all, 60.0);
    EXPECT_GT(means, 65.0);
    EXPECT_GT(covariances, 80.0);
    EXPECT_GT(albedo, 65.0);
    EXPECT_GT(normals, 70.0);
  }
}

TEST(WebExport, FolderIsCompleteAndItsPageLoadsEveryDataScript) {
  WebFixture fx;
  TempFolder tmp;
  const std::string folder = tmp / "web";
  train::export_web_viewer(fx.avatar, fx.motion, fx.camera, folder, false);
  const std::string page = file_text(folder + "/index.html");
  const ViewerFolder viewer(folder);
  EXPECT_NE(page.find("<script src=\"data/manifest.js\"></script>"), std::string::npos);
  for (const auto& name : viewer.manifest["files"])
    EXPECT_NE(page.find("<script src=\"" + name.get<std::string>() + "\"></script>"), std::string::npos) << name;
  for (const char* script : {"viewer.js", "pose_player.js", "depth_sort.js", "splat_renderer.js"}) {
    EXPECT_TRUE(fs::exists(folder + "/" + script)) << script;
    EXPECT_NE(page.find(std::string("<script src=\"") + script + "\"></script>"), std::string::npos) << script;
  }
  EXPECT_EQ(viewer.manifest["frame_buffers"].size(), size_t(kFrames));
  EXPECT_EQ(viewer.manifest["camera"]["width"], kWidth);
  // Nothing beside the folder: the temporary it was written in is gone.
  EXPECT_EQ(std::distance(fs::directory_iterator(tmp.str()), fs::directory_iterator()), 1);
}

TEST(WebExport, ReplacesOnlyEmptyFoldersAndEarlierExports) {
  WebFixture fx;
  fx.motion.frames = 1;
  TempFolder tmp;
  const std::string folder = tmp / "web";
  fs::create_directories(folder);  // an empty folder is taken as it is
  train::export_web_viewer(fx.avatar, fx.motion, fx.camera, folder, false);
  expect_error_mentioning([&] { train::export_web_viewer(fx.avatar, fx.motion, fx.camera, folder, false); },
                          "exists and is not empty (pass --force");
  train::export_web_viewer(fx.avatar, fx.motion, fx.camera, folder, true);  // an earlier export: replaced
  EXPECT_TRUE(fs::exists(folder + "/index.html"));
  // Files a user put beside the viewer: --force refuses, names them, and leaves everything in place.
  write_text(fs::path(folder) / "thesis.tex", "precious");
  fs::create_directories(fs::path(folder) / "mydata");
  write_text(fs::path(folder) / "mydata/notes.txt", "precious");
  expect_error_mentioning([&] { train::export_web_viewer(fx.avatar, fx.motion, fx.camera, folder, true); },
                          "also holds 'mydata/', 'thesis.tex', which the export did not write");
  EXPECT_EQ(file_text(folder + "/thesis.tex"), "precious");
  EXPECT_TRUE(fs::exists(folder + "/index.html"));
  fs::remove(fs::path(folder) / "thesis.tex");
  fs::remove_all(fs::path(folder) / "mydata");
  train::export_web_viewer(fx.avatar, fx.motion, fx.camera, folder, true);
  // An index.html and a manifest that sfgs did not write (empty ones) do not make a folder an export.
  const std::string lookalike = tmp / "lookalike";
  fs::create_directories(fs::path(lookalike) / "data");
  write_text(fs::path(lookalike) / "index.html", "");
  write_text(fs::path(lookalike) / "data/manifest.js", "");
  expect_error_mentioning([&] { train::export_web_viewer(fx.avatar, fx.motion, fx.camera, lookalike, true); },
                          "is not an earlier web export");
  EXPECT_TRUE(fs::exists(lookalike + "/index.html"));

  const std::string run = tmp / "run";
  write_text(tmp / "run/checkpoint.pt", "precious");
  expect_error_mentioning([&] { train::export_web_viewer(fx.avatar, fx.motion, fx.camera, run, true); },
                          "is not an earlier web export");
  EXPECT_EQ(file_text(run + "/checkpoint.pt"), "precious");
  write_text(tmp / "file", "x");
  expect_error_mentioning([&] { train::export_web_viewer(fx.avatar, fx.motion, fx.camera, tmp / "file", true); },
                          "exists and is not a folder");
}

TEST(WebExport, AFailedExportLeavesNothing) {
  WebFixture fx;
  TempFolder tmp;
  const auto pose = fx.motion.pose;
  fx.motion.pose = [&](int64_t i) {
    if (i == 2) throw std::runtime_error("motion file damaged at frame 2");
    return pose(i);
  };
  expect_error_mentioning([&] { train::export_web_viewer(fx.avatar, fx.motion, fx.camera, tmp / "web", false); },
                          "damaged at frame 2");
  EXPECT_EQ(std::distance(fs::directory_iterator(tmp.str()), fs::directory_iterator()), 0);
}

}  // namespace
}  // namespace sfgs::testing
