#include "train/export.h"

#include <algorithm>
#include <cctype>
#include <cstring>
#include <filesystem>
#include <vector>

#include <ATen/ATen.h>

#include "body/rotations.h"
#include "common/atomic_file.h"
#include "common/constants.h"
#include "train/constants.h"
#include "train/run_folder.h"

namespace sfgs::train {
namespace {

constexpr double kShC0 = 0.28209479177387814;  // zeroth spherical-harmonic basis value: colour = 0.5 + C0 * f_dc
constexpr double kOpacityClamp = 1e-6;         // keeps the exported logit finite for opacity 0 or 1
constexpr int64_t kSplatRecordBytes = 32;      // 3 + 3 float32, 4 + 4 bytes

std::vector<unsigned char> bytes_of(const at::Tensor& contiguous_cpu) {
  const auto* begin = static_cast<const unsigned char*>(contiguous_cpu.data_ptr());
  return std::vector<unsigned char>(begin, begin + contiguous_cpu.numel() * contiguous_cpu.element_size());
}

}  // namespace

ExportedGaussians exported_gaussians(model::Avatar& avatar, const data::Dataset* dataset, int64_t frame) {
  at::NoGradGuard no_grad;
  TORCH_CHECK(frame < 0 || (dataset != nullptr && frame < dataset->size()), "export: frame ", frame,
              " is not in the dataset");
  const model::AvatarOutput out =
      frame >= 0 ? pose_avatar(avatar, *dataset, frame) : avatar->forward(body::SmplxPose::zeros(0), std::nullopt);
  at::Tensor means, cov6;
  if (frame >= 0) {
    means = out.means;
    cov6 = out.covariances;
  } else {
    means = out.canonical_means;
    const at::Tensor var = out.log_scales.mul(2).exp();
    const at::Tensor z = at::zeros_like(var);
    cov6 = at::stack({var, z, z, var, z, var}, 1);
  }
  const at::Tensor c = cov6.to(at::kCPU, at::kDouble);
  const at::Tensor full = at::stack({c.select(1, 0), c.select(1, 1), c.select(1, 2), c.select(1, 1), c.select(1, 3),
                                     c.select(1, 4), c.select(1, 2), c.select(1, 4), c.select(1, 5)},
                                    1)
                              .view({-1, 3, 3});
  const auto [eigenvalues, eigenvectors] = at::linalg_eigh(full);
  // Columns are the axes; flip one where needed so the rotation is proper.
  const at::Tensor det_sign = at::sign(at::linalg_det(eigenvectors)).unsqueeze(1).unsqueeze(2);
  const at::Tensor axes = at::cat({eigenvectors.slice(2, 0, 2), eigenvectors.slice(2, 2, 3) * det_sign}, 2);
  ExportedGaussians g;
  g.means = means.to(at::kCPU, at::kFloat).contiguous();
  g.log_scales = at::log(eigenvalues.clamp_min(kMinExportedVariance)).mul(0.5).to(at::kFloat);
  g.rotations = body::matrix_to_quaternion(axes).to(at::kFloat);
  g.colours = out.colours.to(at::kCPU, at::kFloat);
  g.opacities = out.opacities.to(at::kCPU, at::kFloat).clamp(0, 1);
  // The checkpoint was verified finite; this guards the conversions above (eigenvalues, logs) as well.
  for (const at::Tensor* t : {&g.means, &g.log_scales, &g.rotations, &g.colours, &g.opacities}) {
    const int64_t bad = t->numel() - t->isfinite().sum().item<int64_t>();
    TORCH_CHECK(bad == 0, "export: ", bad, " values of the Gaussians are not finite; nothing written");
  }
  return g;
}

void write_ply(const ExportedGaussians& g, const std::string& path, bool overwrite) {
  const at::Tensor f_dc = (g.colours - 0.5) / kShC0;
  const at::Tensor o = g.opacities.clamp(kOpacityClamp, 1 - kOpacityClamp);
  const at::Tensor opacity_logit = at::log(o / (1 - o)).unsqueeze(1);
  const at::Tensor rows =
      at::cat({g.means, at::zeros_like(g.means), f_dc, opacity_logit, g.log_scales, g.rotations}, 1).contiguous();
  std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(rows.size(0)) + "\n";
  for (const char* name : {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
                           "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"})
    header += std::string("property float ") + name + "\n";
  header += "end_header\n";
  std::vector<unsigned char> bytes(header.begin(), header.end());
  const std::vector<unsigned char> body = bytes_of(rows);
  bytes.insert(bytes.end(), body.begin(), body.end());
  write_file_atomically(path, bytes, overwrite);
}

void write_splat(const ExportedGaussians& g, const std::string& path, bool overwrite) {
  const int64_t n = g.means.size(0);
  // Largest and most opaque first: volume (product of the scales) times opacity.
  const at::Tensor order = at::argsort(-(g.log_scales.sum(1).exp() * g.opacities));
  const at::Tensor floats = at::cat({g.means, g.log_scales.exp()}, 1).index_select(0, order).contiguous();
  const at::Tensor rgba = at::cat({g.colours, g.opacities.unsqueeze(1)}, 1).index_select(0, order);
  const at::Tensor colour_bytes = (rgba * 255).round().clamp(0, 255).to(at::kByte);
  const at::Tensor unit = g.rotations.index_select(0, order);
  const at::Tensor rotation_bytes =
      (unit / unit.norm(2, 1, true).clamp_min(kMinQuaternionNorm) * 128 + 128).round().clamp(0, 255).to(at::kByte);
  // One record per Gaussian: the 24 float bytes, then the 8 colour and rotation bytes.
  const at::Tensor records =
      at::cat({floats.view(at::kByte).view({n, 24}), colour_bytes, rotation_bytes}, 1).contiguous();
  TORCH_CHECK(records.size(1) == kSplatRecordBytes, "export: a .splat record must be 32 bytes");
  write_file_atomically(path, bytes_of(records), overwrite);
}

void export_gaussians(model::Avatar& avatar, const data::Dataset* dataset, int64_t frame, const std::string& path,
                      bool overwrite) {
  // Case-insensitive, as bench --out's .png: FILE.PLY is a PLY file.
  std::string extension = std::filesystem::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  TORCH_CHECK(extension == ".ply" || extension == ".splat",
              "export: the file must end in .ply (3DGS) or .splat "
              "(web viewers), got '",
              path, "'");
  const ExportedGaussians g = exported_gaussians(avatar, dataset, frame);
  if (extension == ".ply")
    write_ply(g, path, overwrite);
  else
    write_splat(g, path, overwrite);
}

}  // namespace sfgs::train
