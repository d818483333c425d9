#include "train/evaluate.h"
#include "common/constants.h"

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>

#include <ATen/ATen.h>

#include "common/atomic_file.h"
#include "io/npz.h"
#include "data/image_io.h"
#include "train/run_folder.h"

namespace sfgs::train {
namespace fs = std::filesystem;

namespace {

constexpr double kShC0 = 0.28209479177387814;   // zeroth spherical-harmonic basis value: colour = 0.5 + C0 * f_dc
constexpr double kOpacityClamp = 1e-6;          // keeps the exported logit finite for opacity 0 or 1

// Rotation matrices (N, 3, 3) with det +1 to unit quaternions (w, x, y, z).
at::Tensor quaternions_from_matrices(const at::Tensor& r) {
  const at::Tensor m00 = r.select(1, 0).select(1, 0), m11 = r.select(1, 1).select(1, 1), m22 = r.select(1, 2).select(1, 2);
  const at::Tensor w = 0.5 * at::sqrt((1 + m00 + m11 + m22).clamp_min(0));
  const at::Tensor x = 0.5 * at::sqrt((1 + m00 - m11 - m22).clamp_min(0)) *
                       at::sign(r.select(1, 2).select(1, 1) - r.select(1, 1).select(1, 2));
  const at::Tensor y = 0.5 * at::sqrt((1 - m00 + m11 - m22).clamp_min(0)) *
                       at::sign(r.select(1, 0).select(1, 2) - r.select(1, 2).select(1, 0));
  const at::Tensor z = 0.5 * at::sqrt((1 - m00 - m11 + m22).clamp_min(0)) *
                       at::sign(r.select(1, 1).select(1, 0) - r.select(1, 0).select(1, 1));
  const at::Tensor q = at::stack({w, x, y, z}, 1);
  return q / q.norm(2, 1, true).clamp_min(kMinQuaternionNorm);
}

}  // namespace

AvatarEvaluation evaluate_avatar(const data::Dataset& dataset, data::Split split, model::Avatar& avatar,
                                 const metrics::EvaluationOptions& options, const std::string& save_folder,
                                 bool overwrite) {
  const std::vector<int64_t>& frames = dataset.split(split);
  TORCH_CHECK(!frames.empty(), "dataset '", dataset.source, "' has no frames in the requested split");
  if (!save_folder.empty()) fs::create_directories(save_folder);
  at::NoGradGuard no_grad;
  metrics::ImageEvaluator evaluator(options);
  AvatarEvaluation result;
  const std::optional<RegionTruth> truth = read_region_truth(dataset);
  RegionAccumulator regions(options.ssim_border);
  std::map<int64_t, std::vector<size_t>> frames_of_sequence;
  int64_t previous_sequence = -1, previous_frame = -2;
  double render_ms = 0;
  for (int64_t f : frames) {
    const data::FrameRecord& record = dataset.frames[size_t(f)];
    if (record.sequence != previous_sequence || f != previous_frame + 1) evaluator.begin_sequence();
    previous_sequence = record.sequence;
    previous_frame = f;
    const data::Frame frame = dataset.load(f);
    const auto start = std::chrono::steady_clock::now();
    const model::AvatarOutput out = pose_avatar(avatar, dataset, f);
    const RenderResult r = render(to_gaussians(out), at::ones({3}, out.means.options()), render_camera(record));
    const at::Tensor image = r.image.to(at::kCPU);
    render_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    frames_of_sequence[record.sequence].push_back(result.frames.size());
    result.frames.push_back(evaluator.add_frame(image, frame.image, frame.eval_mask));
    result.frame_names.push_back(record.name);
    if (truth && !record.mesh_path.empty()) {
      const auto [compared_prediction, compared_target] =
          evaluator.compared_images(image, frame.image, frame.eval_mask);
      regions.add(compared_prediction, compared_target,
                  region_masks(*truth, io::read_npy(record.mesh_path), render_camera(record), frame.eval_mask));
    }
    if (!save_folder.empty()) {
      std::string name = record.name;
      std::replace(name.begin(), name.end(), '/', '_');
      data::write_png((fs::path(save_folder) / (name + ".png")).string(), image, overwrite);
    }
  }
  result.summary = evaluator.summary();
  result.regions = regions.summary();
  for (const auto& [sequence, indices] : frames_of_sequence) {
    GroupScore motion;
    motion.name = dataset.sequences[size_t(sequence)];
    for (size_t i : indices) {
      const metrics::FrameMetrics& m = result.frames[i];
      motion.psnr += m.psnr / double(indices.size());
      motion.ssim += m.ssim / double(indices.size());
      if (m.lpips) motion.lpips = motion.lpips.value_or(0.0) + *m.lpips / double(indices.size());
    }
    motion.frames = int64_t(indices.size());
    result.motions.push_back(motion);
  }
  result.render_milliseconds = render_ms / double(frames.size());
  return result;
}

void export_ply(model::Avatar& avatar, const data::Dataset* dataset, int64_t frame, const std::string& path,
                bool overwrite) {
  at::NoGradGuard no_grad;
  TORCH_CHECK(frame < 0 || (dataset != nullptr && frame < dataset->size()), "export: frame ", frame,
              " is not in the dataset");
  const model::AvatarOutput out = frame >= 0 ? pose_avatar(avatar, *dataset, frame)
                                             : avatar->forward(body::SmplxPose::zeros(0), std::nullopt);
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
  means = means.to(at::kCPU, at::kFloat);
  const at::Tensor c = cov6.to(at::kCPU, at::kDouble);
  const at::Tensor full = at::stack({c.select(1, 0), c.select(1, 1), c.select(1, 2), c.select(1, 1), c.select(1, 3),
                                     c.select(1, 4), c.select(1, 2), c.select(1, 4), c.select(1, 5)}, 1).view({-1, 3, 3});
  const auto [eigenvalues, eigenvectors] = at::linalg_eigh(full);
  // Columns are the axes; flip one where needed so the rotation is proper.
  const at::Tensor det_sign = at::sign(at::linalg_det(eigenvectors)).unsqueeze(1).unsqueeze(2);
  const at::Tensor axes = at::cat({eigenvectors.slice(2, 0, 2), eigenvectors.slice(2, 2, 3) * det_sign}, 2);
  const at::Tensor log_scales = at::log(eigenvalues.clamp_min(kMinExportedVariance)).mul(0.5).to(at::kFloat);
  const at::Tensor rotation = quaternions_from_matrices(axes).to(at::kFloat);
  const at::Tensor f_dc = ((out.colours.to(at::kCPU, at::kFloat) - 0.5) / kShC0);
  const at::Tensor o = out.opacities.to(at::kCPU, at::kFloat).clamp(kOpacityClamp, 1 - kOpacityClamp);
  const at::Tensor opacity_logit = at::log(o / (1 - o)).unsqueeze(1);
  const at::Tensor normals = at::zeros_like(means);
  const at::Tensor rows = at::cat({means, normals, f_dc, opacity_logit, log_scales, rotation}, 1).contiguous();
  // The checkpoint was verified finite; this guards the conversions above (eigenvalues, logs) as well.
  const int64_t bad = rows.numel() - rows.isfinite().sum().item<int64_t>();
  TORCH_CHECK(bad == 0, "export: ", bad, " values of the Gaussians are not finite; not writing '", path, "'");

  const int64_t n = rows.size(0);
  std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(n) + "\n";
  for (const char* name : {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
                           "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"})
    header += std::string("property float ") + name + "\n";
  header += "end_header\n";
  std::vector<unsigned char> bytes(header.begin(), header.end());
  const size_t body = size_t(rows.numel()) * sizeof(float);
  bytes.resize(header.size() + body);
  std::memcpy(bytes.data() + header.size(), rows.data_ptr<float>(), body);
  write_file_atomically(path, bytes, overwrite);
}

}  // namespace sfgs::train
