#include "train/pose_fit.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/optim/lbfgs.h>

#include "body/rotations.h"
#include "common/tensor_description.h"
#include "train/constants.h"
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

// Crops start on every stage's pixel grid, and their rounded sizes keep them on it.
constexpr int64_t kCropAlignment = std::lcm(kPoseFitCoarseDownsample, kPoseFitMiddleDownsample);
static_assert(kPoseFitCropStep % kCropAlignment == 0);

// One side of the person's crop on an axis of `extent` pixels whose person pixels span [first, last]: the origin
// and size (the whole axis where the rounded crop would cover it).
std::pair<int64_t, int64_t> crop_axis(int64_t first, int64_t last, int64_t margin, int64_t extent) {
  const int64_t size = (last - first + 1 + 2 * margin + kPoseFitCropStep - 1) / kPoseFitCropStep * kPoseFitCropStep;
  if (size >= extent) return {0, extent};
  const int64_t origin = std::clamp((first + last + 1 - size) / 2, int64_t(0), extent - size);
  return {origin - origin % kCropAlignment, size};
}

// The camera of the crop `box` of its image.
Camera crop(const Camera& camera, const PixelBox& box) {
  Camera c = camera;
  c.cx -= double(box.x);
  c.cy -= double(box.y);
  c.width = box.width;
  c.height = box.height;
  return c;
}

at::Tensor crop(const at::Tensor& image, const PixelBox& box) {
  return image.narrow(0, box.y, box.height).narrow(1, box.x, box.width).contiguous();
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

PixelBox person_crop(const at::Tensor& mask) {
  TORCH_CHECK(mask.dim() == 2, "person_crop: an (H, W) mask expected, got ", describe(mask));
  const int64_t height = mask.size(0), width = mask.size(1);
  const at::Tensor person = mask >= 0.5;
  const at::Tensor rows = at::nonzero(person.any(1)).cpu(), columns = at::nonzero(person.any(0)).cpu();
  if (rows.numel() == 0) return {0, 0, width, height};
  const int64_t top = rows.min().item<int64_t>(), bottom = rows.max().item<int64_t>();
  const int64_t left = columns.min().item<int64_t>(), right = columns.max().item<int64_t>();
  const auto margin = int64_t(std::ceil(kPoseFitCropMargin * double(std::max(bottom - top, right - left) + 1)));
  const auto [x, w] = crop_axis(left, right, margin, width);
  const auto [y, h] = crop_axis(top, bottom, margin, height);
  return {x, y, w, h};
}

FitFrame fit_frame(model::Avatar& avatar, const body::SmplxPose& pose, const PoseFitTarget& target, bool cropped) {
  FitFrame frame;
  frame.pose = pose.views_of(pose.packed().to(target.image.device()));
  {
    at::NoGradGuard no_grad;
    frame.attributes = avatar->attributes(target.time);
  }
  frame.has_time = target.time.has_value();
  frame.keypoints = target.keypoints;
  const int64_t full_width = target.image.size(1), full_height = target.image.size(0);
  const PixelBox box =
      cropped && target.mask.defined() ? person_crop(target.mask) : PixelBox{0, 0, full_width, full_height};
  frame.pixel_share = double(box.width * box.height) / double(full_width * full_height);
  frame.camera = crop(target.camera, box);
  frame.image = crop(target.image, box);
  if (target.mask.defined()) frame.mask = crop(target.mask, box);
  return frame;
}

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
  TORCH_CHECK(std::isfinite(options.stall_share) && options.stall_share >= 0 && options.stall_share < 1,
              "pose fitting: the stall share must be in [0, 1), got ", options.stall_share);
  fit_loss_ = std::make_unique<FitLoss>(loss_, keypoint_map_ ? &*keypoint_map_ : nullptr, options.keypoint_weight,
                                        options.gradient);
}

PoseFitter::~PoseFitter() = default;

PoseFitResult PoseFitter::fit(model::Avatar& avatar, const body::SmplxPose& pose, const PoseFitTarget& target,
                              const at::Tensor& start) {
  const at::Device device = target.image.device();
  // The frame as each stage's resolution sees it; the fit and the pose-independent attributes once for every stage.
  FitFrame cropped = fit_frame(avatar, pose, target, true);
  if (!keypoint_map_) cropped.keypoints = FrameKeypoints();
  std::array<FitFrame, kStages.size()> frames;
  for (size_t s = 0; s < kStages.size(); ++s) {
    const int64_t d = kStages[s].downsample;
    frames[s] = cropped;
    if (d == 1) continue;
    frames[s].camera = downsampled(cropped.camera, d);
    frames[s].image = downsample(cropped.image, d);
    if (cropped.mask.defined()) frames[s].mask = downsample(cropped.mask, d);
  }

  const bool record = options_.recorded && device.is_cuda() && device_graphs_available() && !recording_failed_;
  if (record && (!graphs_ || graphs_->avatar().get() != avatar.get()))
    graphs_ = std::make_unique<PoseFitGraphs>(avatar, *fit_loss_, device);
  PoseFitResult result;
  result.recorded = record;
  size_t loaded = kStages.size();  // the stage whose frame the recorded evaluations read
  // The stage's loss at `correction` (CPU) and, where it is finite, its gradient.
  const auto evaluate = [&](size_t s, const at::Tensor& correction) -> FitEvaluation {
    ++result.evaluations;
    if (graphs_) {
      try {
        if (loaded != s) graphs_->load(frames[s], kStages[s].run_loss);
        loaded = s;
        return graphs_->evaluate(correction);
      } catch (const GraphCaptureError& e) {
        // An evaluation the graphs cannot hold is still an evaluation: this one and the rest run eagerly.
        std::fprintf(stderr, "pose fitting: evaluating eagerly (%s)\n", e.what());
        recording_failed_ = true;
        result.recorded = false;
        graphs_.reset();
      }
    }
    const at::Tensor moving = correction.to(device, at::kFloat, false, /*copy=*/true).requires_grad_(true);
    const at::Tensor loss = (*fit_loss_)(avatar, frames[s], moving, kStages[s].run_loss);
    FitEvaluation e{loss.item<double>(), at::Tensor()};
    if (std::isfinite(e.loss)) e.gradient = torch::autograd::grad({loss}, {moving})[0].to(at::kCPU, at::kFloat);
    return e;
  };

  const size_t fine = kStages.size() - 1;
  at::Tensor best = start.detach().to(at::kCPU, at::kFloat).clone();
  result.start_loss = evaluate(fine, best).loss;
  int64_t done = 0;
  for (size_t s = 0; s < kStages.size(); ++s) {
    const StageSpec& spec = kStages[s];
    const bool last = s == fine;
    const int64_t end =
        last ? options_.iterations : done + int64_t(std::llround(spec.share * double(options_.iterations)));
    const int64_t evaluations = end - done;
    // A coarser stage of one evaluation would render once and never step: its share goes to the fine stage.
    if (evaluations <= 0 || (!last && evaluations < kPoseFitMinStageEvaluations)) continue;
    done = end;
    // L-BFGS models how the joints' corrections couple along the kinematic chain (a turned root and a twisted spine
    // move the same pixels); its line search picks each step's length, so no rate needs tuning to the noise level.
    // Its few hundred numbers live on the host, where its decisions are made.
    at::Tensor moving = at::full({kCorrectionWidth}, spec.all_columns && options_.fit_joints ? 1.0f : 0.0f);
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
    std::vector<double> best_after;  // the best loss after each evaluation of the stage
    const auto stalled = [&] {
      if (options_.stall_share <= 0 || spent <= kPoseFitStallEvaluations) return false;
      const double earlier = best_after[size_t(spent - 1 - kPoseFitStallEvaluations)];
      return earlier - best_loss <= options_.stall_share * std::abs(earlier);
    };
    const auto stage_loss = [&]() -> at::Tensor {
      if (spent == evaluations || stalled()) throw StageEnded{};
      ++spent;
      const FitEvaluation e = evaluate(s, correction.detach());
      if (!std::isfinite(e.loss)) throw StageEnded{};
      // A stage that moves the placement alone sees no joint gradient.
      at::NoGradGuard no_grad;
      correction.mutable_grad() = e.gradient * moving;
      if (e.loss < best_loss) {
        best_loss = e.loss;
        best = correction.detach().clone();
      }
      best_after.push_back(best_loss);
      return at::scalar_tensor(e.loss, at::kFloat);
    };
    try {
      optimizer.step(stage_loss);
    } catch (const StageEnded&) {
    }
    if (last) result.loss = best_loss;
  }
  if (!(result.loss < result.start_loss)) {  // nothing beat the start
    best = start.detach().to(at::kCPU, at::kFloat).clone();
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
  PoseFitter fitter(options, device, keypoint_map);
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
