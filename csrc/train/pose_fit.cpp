#include "train/pose_fit.h"

#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <string>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/optim/lbfgs.h>

#include "body/rotations.h"
#include "common/constants.h"
#include "data/keypoint_file.h"
#include "train/avatar_keypoints.h"
#include "train/run_folder.h"

namespace sfgs::train {
namespace {

// (H, W, C) or (H, W) averaged over `factor` x `factor` blocks (the right and bottom remainders dropped).
at::Tensor downsample(const at::Tensor& values, int64_t factor) {
  const bool planar = values.dim() == 2;
  const at::Tensor chw = (planar ? values.unsqueeze(2) : values).permute({2, 0, 1}).unsqueeze(0);
  const at::Tensor pooled = at::avg_pool2d(chw, {factor, factor}).squeeze(0).permute({1, 2, 0});
  return planar ? pooled.squeeze(2) : pooled.contiguous();
}

// The camera of a `factor` times coarser image of the same view: pixel (i, j) covers pixels [factor i, factor (i +
// 1)) of the full image, so its centre maps to the same ray when the focal lengths and principal point are divided.
Camera downsampled(const Camera& camera, int64_t factor) {
  Camera c = camera;
  c.fx /= double(factor);
  c.fy /= double(factor);
  c.cx /= double(factor);
  c.cy /= double(factor);
  c.width = camera.width / factor;
  c.height = camera.height / factor;
  return c;
}

// One stage of a fit: its share of the evaluations, resolution, which correction columns move, and its loss.
struct StageSpec {
  double share;
  int64_t downsample;
  bool all_columns;  // else the placement alone (the translation, and the global orientation where it is fitted)
  bool run_loss;     // the run's image loss inside the person (else L1 of the whole image) plus the silhouette
};
const std::array<StageSpec, 3> kStages{{{kPoseFitCoarseShare, kPoseFitCoarseDownsample, false, false},
                                        {kPoseFitMiddleShare, kPoseFitMiddleDownsample, true, false},
                                        {1 - kPoseFitCoarseShare - kPoseFitMiddleShare, 1, true, true}}};

// Thrown by a stage's loss when its evaluations are spent or the loss is not finite: ends the stage's L-BFGS run
// where it stands (the stage keeps its best iterate), so a fit costs at most its evaluations (L-BFGS may also stop
// early, at a zero gradient or a failed line search) and a NaN from a wild line-search trial never becomes an
// iterate.
struct StageEnded {};

}  // namespace

PoseFitTarget pose_fit_target(const data::Dataset& dataset, int64_t frame, at::Device device, bool with_keypoints) {
  const data::FrameRecord& record = dataset.frames[size_t(frame)];
  const data::Frame loaded = dataset.load(frame);
  PoseFitTarget t;
  t.camera = render_camera(record);
  t.time = dataset.replay_time(frame);
  t.image = loaded.image.to(device);
  if (with_keypoints) t.keypoints = record_keypoints(record, device);
  if (!record.mask_path.empty()) {  // without a mask the whole image is the target and there is no silhouette
    t.mask = loaded.mask.to(device);
    const at::Tensor m = t.mask.unsqueeze(2);
    t.image = t.image * m + (1 - m);
  }
  return t;
}

FrameKeypoints record_keypoints(const data::FrameRecord& record, at::Device device) {
  if (record.keypoints_path.empty()) return {};
  return frame_keypoints(data::read_wholebody_keypoints(record.keypoints_path).to(device), render_camera(record));
}

PoseFitter::PoseFitter(const PoseFitOptions& options, at::Device device, const body::WholeBodyKeypointMap* keypoint_map)
    : options_(options), loss_(options.loss, device) {
  TORCH_CHECK(std::isfinite(options.keypoint_weight) && options.keypoint_weight >= 0,
              "pose fitting: the keypoint weight must be finite and >= 0, got ", options.keypoint_weight);
  if (keypoint_map && options.keypoint_weight > 0) keypoint_map_ = keypoint_map->to(device, at::kFloat);
}

PoseFitResult PoseFitter::fit(model::Avatar& avatar, const body::SmplxPose& pose, const PoseFitTarget& target,
                              const at::Tensor& start) const {
  const auto options = start.options();
  const at::Tensor white = at::ones({3}, options);
  // The image (and mask) at each stage's resolution.
  struct Level {
    Camera camera;
    at::Tensor image, mask;
  };
  std::map<int64_t, Level> levels;
  for (const StageSpec& spec : kStages) {
    if (levels.count(spec.downsample)) continue;
    const int64_t d = spec.downsample;
    levels[d] = d == 1 ? Level{target.camera, target.image, target.mask}
                       : Level{downsampled(target.camera, d), downsample(target.image, d),
                               target.mask.defined() ? downsample(target.mask, d) : at::Tensor()};
  }
  const bool anchored = keypoint_map_.has_value() && target.keypoints.defined();
  const auto image_loss = [&](const RenderResult& r, const Level& level, const StageSpec& spec) {
    if (!spec.run_loss) {
      const at::Tensor loss = (r.image - level.image).abs().mean();
      return level.mask.defined() ? loss + kPoseFitSilhouetteWeight * (r.alpha - level.mask).abs().mean() : loss;
    }
    // The image inside the person, as the evaluation protocol sees it, and the silhouette.
    LossTerms terms;
    if (!level.mask.defined()) {
      loss_.add_terms(r.image, level.image, terms);
      return total_loss(terms);
    }
    const at::Tensor m = level.mask.unsqueeze(2);
    loss_.add_terms(r.image * m + (1 - m), level.image, terms);
    return total_loss(terms) + kPoseFitFineSilhouetteWeight * (r.alpha - level.mask).abs().mean();
  };
  const auto loss_of = [&](const at::Tensor& correction, const StageSpec& spec) {
    const Level& level = levels.at(spec.downsample);
    const model::AvatarOutput out = avatar->forward_trusted_pose(corrected_pose(pose, correction), target.time);
    const at::Tensor loss = image_loss(render(model::to_gaussians(out), white, level.camera), level, spec);
    if (!anchored) return loss;
    return loss + options_.keypoint_weight * keypoint_reprojection_loss(*keypoint_map_, avatar, out, target.keypoints);
  };

  PoseFitResult result;
  {
    at::NoGradGuard no_grad;
    result.start_loss = loss_of(start, kStages[2]).item<double>();
  }
  at::Tensor best = start.detach().clone();
  int64_t done = 0;
  for (size_t s = 0; s < kStages.size(); ++s) {
    const StageSpec& spec = kStages[s];
    const bool last = s + 1 == kStages.size();
    const int64_t end =
        last ? options_.iterations : done + int64_t(std::llround(spec.share * double(options_.iterations)));
    const int64_t evaluations = end - done;
    // A coarser stage of one evaluation would render once and never step: its share goes to the fine stage.
    if (evaluations <= 0 || (!last && evaluations < kPoseFitMinStageEvaluations)) continue;
    done = end;
    // L-BFGS models how the joints' corrections couple along the kinematic chain (a turned root and a twisted spine
    // move the same pixels); its line search picks each step's length, so no rate needs tuning to the noise level.
    at::Tensor moving = at::full({kCorrectionWidth}, spec.all_columns && options_.fit_joints ? 1.0 : 0.0, options);
    moving.narrow(0, 0, 3).fill_(options_.fit_orientation ? 1.0 : 0.0);
    moving.narrow(0, kCorrectionWidth - 3, 3).fill_(1.0);
    at::Tensor correction = best.clone().requires_grad_(true);
    torch::optim::LBFGS optimizer({correction}, torch::optim::LBFGSOptions(1.0)
                                                    .max_iter(evaluations)
                                                    .max_eval(evaluations)
                                                    .history_size(kPoseFitHistory)
                                                    .tolerance_grad(0)
                                                    .tolerance_change(0)
                                                    .line_search_fn("strong_wolfe"));
    double best_loss = INFINITY;
    int64_t spent = 0;
    const auto stage_loss = [&]() -> at::Tensor {
      if (spent == evaluations) throw StageEnded{};
      ++spent;
      const at::Tensor loss = loss_of(correction, spec);
      const double value = loss.item<double>();
      if (!std::isfinite(value)) throw StageEnded{};
      // The gradient of the correction alone (the frozen avatar's parameters accumulate none); a stage that moves
      // the placement alone sees no joint gradient.
      const at::Tensor gradient = torch::autograd::grad({loss}, {correction})[0];
      at::NoGradGuard no_grad;
      correction.mutable_grad() = gradient * moving;
      if (value < best_loss) {
        best_loss = value;
        best = correction.detach().clone();
      }
      return loss.detach();
    };
    try {
      optimizer.step(stage_loss);
    } catch (const StageEnded&) {
    }
    if (last) result.loss = best_loss;
  }
  if (!(result.loss < result.start_loss)) {  // nothing beat the start
    best = start.detach().clone();
    result.loss = result.start_loss;
  }
  result.correction = best;
  return result;
}

PoseError pose_error(const body::SmplxPose& fit, const body::SmplxPose& truth) {
  // Mean geodesic angle in degrees between (J, 3) axis-angles.
  const auto angle = [](const at::Tensor& a, const at::Tensor& b) {
    const at::Tensor ra = body::axis_angle_to_matrix(a.reshape({-1, 3}).to(at::kCPU, at::kDouble));
    const at::Tensor rb = body::axis_angle_to_matrix(b.reshape({-1, 3}).to(at::kCPU, at::kDouble));
    const at::Tensor cosine = ((ra.transpose(1, 2).matmul(rb)).diagonal(0, 1, 2).sum(1) - 1) / 2;
    return at::acos(cosine.clamp(-1, 1)).mean().item<double>() * 180 / M_PI;
  };
  PoseError e;
  e.root = angle(fit.global_orient, truth.global_orient);
  e.body = angle(fit.body_pose, truth.body_pose);
  const bool hands = fit.left_hand_pose.defined() && truth.left_hand_pose.defined() && fit.right_hand_pose.defined() &&
                     truth.right_hand_pose.defined();
  if (hands)
    e.hands =
        0.5 * (angle(fit.left_hand_pose, truth.left_hand_pose) + angle(fit.right_hand_pose, truth.right_hand_pose));
  e.translation =
      100 * (fit.transl.to(at::kCPU, at::kDouble) - truth.transl.to(at::kCPU, at::kDouble)).norm().item<double>();
  return e;
}

std::string to_string(const PoseError& e) {
  char text[160];
  std::snprintf(text, sizeof(text), "root %.2f deg, body %.2f deg, hands %.2f deg, translation %.2f cm", e.root, e.body,
                e.hands, e.translation);
  return text;
}

data::Dataset fit_poses(const data::Dataset& dataset, data::Split split, model::Avatar& avatar,
                        const PoseFitOptions& options, const body::WholeBodyKeypointMap* keypoint_map, bool progress) {
  data::Dataset fitted = dataset;
  const std::vector<int64_t>& frames = dataset.split(split);
  const at::Device device = avatar->part_labels().device();
  const PoseFitter fitter(options, device, keypoint_map);
  const at::Tensor zero = at::zeros({kCorrectionWidth}, at::TensorOptions().device(device));
  for (size_t k = 0; k < frames.size(); ++k) {
    const int64_t f = frames[k];
    const data::FrameRecord& record = dataset.frames[size_t(f)];
    const PoseFitResult r =
        fitter.fit(avatar, record.pose, pose_fit_target(dataset, f, device, fitter.uses_keypoints()), zero);
    body::SmplxPose p = corrected_pose(record.pose, r.correction.cpu());
    fitted.frames[size_t(f)].pose = p;
    if (!progress) continue;
    std::printf("  fitted the pose of %s (%zu/%zu): loss %.4f -> %.4f\n", record.name.c_str(), k + 1, frames.size(),
                r.start_loss, r.loss);
    if (record.true_pose)
      std::printf("    against the exact fit: %s -> %s\n",
                  to_string(pose_error(record.pose, *record.true_pose)).c_str(),
                  to_string(pose_error(p, *record.true_pose)).c_str());
  }
  return fitted;
}

}  // namespace sfgs::train
