#include "fit/fit_accuracy.h"

#include <ATen/ATen.h>

#include <filesystem>
#include <nlohmann/json.hpp>
#include <vector>

#include "body/skeleton.h"
#include "fit/constants.h"
#include "data/dataset.h"
#include "data/json_values.h"
#include "data/neuman.h"

namespace sfgs::fit {
namespace fs = std::filesystem;

namespace {

constexpr int64_t kBodyJoints = 22;  // pelvis .. right wrist
constexpr double kMillimetres = 1000.0;

ReferenceFits read_parameter_folder(const std::string& folder) {
  ReferenceFits r;
  r.source = folder;
  const fs::path shape = fs::path(folder) / "shape_param.json";
  r.betas = data::json_numbers(data::read_json_file(shape.string()), {-1}, shape.string());
  const fs::path params = fs::path(folder) / "smplx_params";
  TORCH_CHECK(fs::is_directory(params), "exact fits '", folder, "' have no smplx_params/ folder");
  for (const fs::directory_entry& e : fs::directory_iterator(params)) {
    const std::string stem = e.path().stem().string();
    if (e.path().extension() != ".json" || stem.empty() || stem.find_first_not_of("0123456789") != std::string::npos)
      continue;
    r.poses[std::stoll(stem)] = data::read_exavatar_pose(e.path().string());
  }
  return r;
}

std::array<double, 16> identity_matrix() { return {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1}; }

// Posed joints and vertices of poses (B) in camera coordinates, evaluated in chunks.
struct Posed {
  at::Tensor joints, vertices;
};

Posed pose_in_camera(const body::SmplxModelData& model, const std::vector<body::SmplxPose>& poses,
                     const at::Tensor& betas, bool hands_relative, const std::vector<at::Tensor>& world_to_camera) {
  body::SmplxOptions o;
  o.num_betas = std::min<int64_t>(betas.size(0), model.shapedirs.size(2));
  o.num_expression_coeffs = std::min<int64_t>(poses[0].expression.size(0), model.exprdirs.size(2));
  o.use_pca = false;
  o.flat_hand_mean = !hands_relative;
  o.dtype = at::kDouble;
  const body::Smplx layer(model, o);
  std::vector<at::Tensor> joints, vertices;
  for (size_t begin = 0; begin < poses.size(); begin += size_t(kFitAccuracyChunk)) {
    const size_t end = std::min(poses.size(), begin + size_t(kFitAccuracyChunk));
    body::SmplxInput in;
    in.pose =
        body::SmplxPose::stack(std::vector<body::SmplxPose>(poses.begin() + long(begin), poses.begin() + long(end)))
            .to(at::TensorOptions().dtype(at::kDouble));
    in.pose.expression = in.pose.expression.narrow(1, 0, o.num_expression_coeffs);
    in.betas = betas.to(at::kDouble).narrow(0, 0, o.num_betas).unsqueeze(0).expand({long(end - begin), -1});
    const body::SmplxOutput out = layer->forward(in);
    at::Tensor j = out.joints, v = out.vertices;
    if (!world_to_camera.empty()) {
      const at::Tensor m = at::stack(
          std::vector<at::Tensor>(world_to_camera.begin() + long(begin), world_to_camera.begin() + long(end)));
      const at::Tensor r = m.narrow(1, 0, 3).narrow(2, 0, 3), t = m.narrow(1, 0, 3).select(2, 3).unsqueeze(1);
      j = j.matmul(r.transpose(1, 2)) + t;
      v = v.matmul(r.transpose(1, 2)) + t;
    }
    joints.push_back(j);
    vertices.push_back(v);
  }
  return {at::cat(joints), at::cat(vertices)};
}

// Mean per-joint error after the best similarity transform of each frame's `a` (B, J, 3) onto `b`.
at::Tensor procrustes_errors(const at::Tensor& a, const at::Tensor& b) {
  const at::Tensor ma = a.mean(1, true), mb = b.mean(1, true);
  const at::Tensor x = a - ma, y = b - mb;
  const auto [u, s, vh] = at::linalg_svd(x.transpose(1, 2).matmul(y), true);
  // Rotation x -> y that keeps a proper rotation (no reflection).
  const at::Tensor d = at::linalg_det(vh.transpose(1, 2).matmul(u.transpose(1, 2))).sign();
  at::Tensor e = at::ones_like(s);
  e.select(1, 2).copy_(d);
  const at::Tensor r = vh.transpose(1, 2).matmul(at::diag_embed(e)).matmul(u.transpose(1, 2));
  const at::Tensor scale = (s * e).sum(1) / x.square().sum({1, 2}).clamp_min(1e-12);
  const at::Tensor aligned = scale.view({-1, 1, 1}) * x.matmul(r.transpose(1, 2)) + mb;
  return (aligned - b).norm(2, -1);
}

}  // namespace

std::optional<ReferenceFits> find_reference_fits(const std::string& data, const std::string& truth) {
  if (!truth.empty()) {
    TORCH_CHECK(fs::is_directory(truth), "--truth '", truth,
                "' is not a folder (expected shape_param.json and "
                "smplx_params/<frame>.json in camera coordinates)");
    try {
      return read_parameter_folder(truth);
    } catch (const c10::Error& e) {
      TORCH_CHECK(false, "--truth '", truth, "': ", e.what_without_backtrace(),
                  " (expected shape_param.json and smplx_params/<frame>.json in camera coordinates)");
    }
  }
  const fs::path ground_truth = fs::path(data) / "ground_truth";
  if (fs::is_directory(ground_truth)) return read_parameter_folder(ground_truth.string());
  if (!fs::exists(fs::path(data) / "dataset.json")) return std::nullopt;
  const data::Dataset d = data::read_sfgs_dataset(data);
  ReferenceFits r;
  const bool exact = d.true_betas.defined();
  r.source = (fs::path(data) / "dataset.json").string() + (exact ? " (exact fits)" : " (its fits)");
  r.betas = exact ? d.true_betas : d.betas;
  r.hands_relative_to_mean = true;  // as sfgs synth writes them (docs/dataset_format.md)
  for (int64_t i = 0; i < d.size(); ++i) {
    const data::FrameRecord& f = d.frames[size_t(i)];
    r.poses[i] = f.true_pose ? *f.true_pose : f.pose;
    const auto m = f.pose_in_camera_frame ? identity_matrix() : f.camera.world_to_camera;
    r.world_to_camera[i] = at::tensor(std::vector<double>(m.begin(), m.end()), at::kDouble).view({4, 4});
  }
  return r;
}

FitAccuracy measure_accuracy(const body::SmplxModelData& model, const std::map<int64_t, body::SmplxPose>& fitted,
                             const at::Tensor& fitted_betas, const ReferenceFits& reference) {
  std::vector<body::SmplxPose> mine, theirs;
  std::vector<at::Tensor> cameras;
  for (const auto& [number, pose] : fitted) {
    const auto it = reference.poses.find(number);
    if (it == reference.poses.end()) continue;
    mine.push_back(pose);
    theirs.push_back(it->second);
    if (!reference.world_to_camera.empty()) cameras.push_back(reference.world_to_camera.at(number));
  }
  TORCH_CHECK(!mine.empty(), "exact fits '", reference.source, "' share no frame with the fit");
  const Posed a = pose_in_camera(model, mine, fitted_betas, true, {});
  const Posed b = pose_in_camera(model, theirs, reference.betas, reference.hands_relative_to_mean, cameras);
  const auto mean_mm = [](const at::Tensor& t) { return t.mean().item<double>() * kMillimetres; };
  const at::Tensor pelvis_a = a.joints.narrow(1, 0, 1), pelvis_b = b.joints.narrow(1, 0, 1);
  const at::Tensor body_a = a.joints.narrow(1, 0, kBodyJoints), body_b = b.joints.narrow(1, 0, kBodyJoints);
  FitAccuracy acc;
  acc.reference = reference.source;
  acc.frames = int64_t(mine.size());
  acc.mpjpe_mm = mean_mm(((body_a - pelvis_a) - (body_b - pelvis_b)).norm(2, -1));
  acc.mpjpe_absolute_mm = mean_mm((body_a - body_b).norm(2, -1));
  acc.pa_mpjpe_mm = mean_mm(procrustes_errors(body_a, body_b));
  std::vector<at::Tensor> hand_errors;
  for (body::Side side : {body::Side::kLeft, body::Side::kRight}) {
    const int64_t wrist = body::smplx_hand_joint(side, 0), first = body::smplx_hand_joint(side, 1);
    const auto local = [&](const at::Tensor& j) {
      return j.narrow(1, first, body::kHandJointCount) - j.narrow(1, wrist, 1);
    };
    hand_errors.push_back((local(a.joints) - local(b.joints)).norm(2, -1));
  }
  acc.hand_mpjpe_mm = mean_mm(at::cat(hand_errors, 1));
  acc.vertex_error_mm = mean_mm(((a.vertices - pelvis_a) - (b.vertices - pelvis_b)).norm(2, -1));
  acc.vertex_error_absolute_mm = mean_mm((a.vertices - b.vertices).norm(2, -1));
  acc.depth_error_mm = mean_mm((pelvis_a.select(2, 2) - pelvis_b.select(2, 2)).abs());
  return acc;
}

}  // namespace sfgs::fit
