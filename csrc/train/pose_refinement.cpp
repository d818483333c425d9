#include "train/pose_refinement.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "train/constants.h"
#include "data/json_values.h"
#include "train/avatar_keypoints.h"
#include "train/fit_smoothing.h"
#include "train/pose_fit.h"
#include "train/run_folder.h"

namespace sfgs::train {
namespace {

// Where each corrected field lies in a correction (and in the refined-fits JSON): name, first column, joints.
struct CorrectedField {
  const char* name;
  at::Tensor body::SmplxPose::*member;
  int64_t first, joints;
};
constexpr int64_t kBodyColumn = 3;
constexpr int64_t kJawColumn = kBodyColumn + 3 * body::kSmplxBodyJointCount;
constexpr int64_t kLeftHandColumn = kJawColumn + 3;
constexpr int64_t kRightHandColumn = kLeftHandColumn + body::kHandPoseSize;
constexpr int64_t kTranslationColumn = kRightHandColumn + body::kHandPoseSize;
static_assert(kTranslationColumn == 3 * kCorrectedJoints && kTranslationColumn + 3 == kCorrectionWidth);
const std::array<CorrectedField, 6>& corrected_fields() {
  using body::SmplxPose;
  static const std::array<CorrectedField, 6> fields{
      {{"global_orient", &SmplxPose::global_orient, 0, 1},
       {"body_pose", &SmplxPose::body_pose, kBodyColumn, body::kSmplxBodyJointCount},
       {"jaw_pose", &SmplxPose::jaw_pose, kJawColumn, 1},
       {"left_hand_pose", &SmplxPose::left_hand_pose, kLeftHandColumn, body::kHandJointCount},
       {"right_hand_pose", &SmplxPose::right_hand_pose, kRightHandColumn, body::kHandJointCount},
       {"transl", &SmplxPose::transl, kTranslationColumn, 1}}};
  return fields;
}

// The corrected fields of a fit as one row (kCorrectionWidth), float32 on the CPU; undefined fields as zeros.
at::Tensor fit_row(const body::SmplxPose& pose) {
  at::Tensor row = at::zeros({kCorrectionWidth});
  for (const CorrectedField& f : corrected_fields()) {
    const at::Tensor& value = pose.*(f.member);
    if (value.defined()) row.narrow(0, f.first, 3 * f.joints).copy_(value.reshape({-1}).to(at::kFloat));
  }
  return row;
}

// The first iteration at or after `share` of a run of `iterations`.
int64_t iteration_at(double share, int64_t iterations) { return int64_t(std::ceil(share * double(iterations))); }

}  // namespace

body::SmplxPose corrected_pose(const body::SmplxPose& base, const at::Tensor& correction) {
  TORCH_CHECK(correction.dim() == 1 && correction.size(0) == kCorrectionWidth, "corrected_pose: a correction has ",
              kCorrectionWidth, " values, got shape ", correction.sizes());
  body::SmplxPose p = base;
  const auto options = correction.options();
  for (const CorrectedField& f : corrected_fields()) {
    const at::Tensor& given = base.*(f.member);
    if (!given.defined() &&
        (f.member == &body::SmplxPose::left_hand_pose || f.member == &body::SmplxPose::right_hand_pose))
      continue;  // the avatar skips an absent hand: it stays absent
    const at::Tensor delta = correction.narrow(0, f.first, 3 * f.joints);
    const at::Tensor value = given.defined() ? given.reshape({-1}).to(options) + delta : delta;
    p.*(f.member) = f.joints == 1 ? value : value.view({f.joints, 3});
  }
  return p;
}

PoseRefinement::PoseRefinement(const data::Dataset& dataset, const PoseRefinementConfig& config, int64_t iterations,
                               at::Device device, const body::WholeBodyKeypointMap* keypoint_map)
    : dataset_(dataset), config_(config), row_(size_t(dataset.size()), -1) {
  frames_ = dataset.split(data::Split::kTrain);
  TORCH_CHECK(!frames_.empty(), "pose refinement: dataset '", dataset.source, "' has no training frames");
  std::stable_sort(frames_.begin(), frames_.end(), [&](int64_t a, int64_t b) {
    const data::FrameRecord &x = dataset.frames[size_t(a)], &y = dataset.frames[size_t(b)];
    return x.sequence != y.sequence ? x.sequence < y.sequence : x.time < y.time;
  });
  const int64_t rows = int64_t(frames_.size());
  std::vector<at::Tensor> fits;
  for (int64_t r = 0; r < rows; ++r) {
    row_[size_t(frames_[size_t(r)])] = r;
    fits.push_back(fit_row(dataset.frames[size_t(frames_[size_t(r)])].pose));
  }
  base_ = at::stack(fits).to(device);
  corrections_ = at::zeros({rows, kCorrectionWidth}, at::TensorOptions().dtype(at::kFloat).device(device));
  smooth_refined_fits();
  keep_fits_on_host();
  for (const double share : config.align_at) align_iterations_.push_back(iteration_at(share, iterations));
  align_joints_from_ = iteration_at(config.align_joints_from, iterations);
  align_orientation_from_ = iteration_at(config.align_orientation_from, iterations);
  if (!keypoint_map || config.keypoint_weight <= 0) return;
  keypoints_.resize(size_t(rows));
  bool any = false;
  for (int64_t r = 0; r < rows; ++r) {
    keypoints_[size_t(r)] = record_keypoints(dataset.frames[size_t(frames_[size_t(r)])], device);
    any = any || keypoints_[size_t(r)].defined();
  }
  if (any) keypoint_map_ = keypoint_map->to(device, at::kFloat);
}

int64_t PoseRefinement::row_of(int64_t frame) const {
  TORCH_CHECK(frame >= 0 && frame < int64_t(row_.size()) && row_[size_t(frame)] >= 0, "pose refinement: frame ", frame,
              " is not a training frame");
  return row_[size_t(frame)];
}

nlohmann::json PoseRefinement::align(int64_t iteration, model::Avatar& avatar, const LossWeights& loss, bool recorded) {
  if (std::find(align_iterations_.begin(), align_iterations_.end(), iteration) == align_iterations_.end())
    return nlohmann::json::object();
  PoseFitOptions options;
  options.iterations = config_.align_iterations;
  options.loss = loss;
  options.fit_orientation = iteration >= align_orientation_from_;
  options.fit_joints = iteration >= align_joints_from_;
  options.keypoint_weight = config_.keypoint_weight;
  options.recorded = recorded;
  // Hundreds of fits a training: the skeleton's gradient, and a stage ends where its loss stalls.
  options.gradient = model::PoseGradient::kSkeleton;
  options.stall_share = kAlignmentStallShare;
  const auto started = std::chrono::steady_clock::now();
  const at::Device device = corrections_.device();
  PoseFitter fitter(options, device, keypoint_map_ ? &*keypoint_map_ : nullptr);
  // The parameters hold still meanwhile: the avatar's pose-independent features are computed once, not per step.
  avatar->eval();
  avatar->cache_static_features();
  const nlohmann::json error_before = error_against_truth();
  double before = 0, after = 0;
  int64_t evaluations = 0;
  bool every_fit_recorded = true;
  for (size_t r = 0; r < frames_.size(); ++r) {
    const int64_t f = frames_[r];
    // The frame's detections as the constructor read them (a pass reads no keypoint file).
    PoseFitTarget target = pose_fit_target(dataset_, f, device, false);
    if (keypoint_map_) target.keypoints = keypoints_[r];
    const PoseFitResult fit =
        fitter.fit(avatar, dataset_.frames[size_t(f)].pose, target, corrections_[int64_t(r)].clone());
    corrections_[int64_t(r)].copy_(fit.correction);
    before += fit.start_loss;
    after += fit.loss;
    evaluations += fit.evaluations;
    every_fit_recorded = every_fit_recorded && fit.recorded;
  }
  avatar->clear_cache();
  avatar->train();
  const nlohmann::json error_aligned = config_.smoothing_seconds > 0 ? error_against_truth() : nlohmann::json();
  smooth_refined_fits();
  keep_fits_on_host();
  const double rows = double(frames_.size());
  nlohmann::json entry{{"event", "pose_alignment"},
                       {"iteration", iteration},
                       {"frames", frames_.size()},
                       {"loss_before", before / rows},
                       {"loss_after", after / rows},
                       {"evaluations", evaluations},
                       {"recorded", every_fit_recorded},
                       {"seconds", std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count()}};
  const nlohmann::json error = error_against_truth();
  if (!error.empty()) {
    entry["pose_error_before"] = error_before;
    entry["pose_error"] = error;
    if (!error_aligned.is_null()) entry["pose_error_unsmoothed"] = error_aligned;
  }
  return entry;
}

void PoseRefinement::smooth_refined_fits() {
  if (config_.smoothing_seconds <= 0) return;
  std::vector<double> times;
  std::vector<int64_t> sequences;
  for (const int64_t f : frames_) {
    times.push_back(dataset_.frames[size_t(f)].time);
    sequences.push_back(dataset_.frames[size_t(f)].sequence);
  }
  const at::Tensor refined = base_ + corrections_;
  corrections_.copy_(smooth_fits(refined, kCorrectedJoints, times, sequences, config_.smoothing_seconds) - base_);
}

nlohmann::json PoseRefinement::error_against_truth() const {
  const auto as_json = [](const PoseError& e) {
    return nlohmann::json{
        {"root_deg", e.root}, {"body_deg", e.body}, {"hands_deg", e.hands}, {"translation_cm", e.translation}};
  };
  PoseError input, refined;
  int64_t count = 0;
  const at::Tensor corrections = corrections_.cpu();
  for (size_t r = 0; r < frames_.size(); ++r) {
    const data::FrameRecord& record = dataset_.frames[size_t(frames_[r])];
    if (!record.true_pose) continue;
    for (auto [sum, pose] : {std::pair<PoseError*, body::SmplxPose>{&input, record.pose},
                             {&refined, corrected_pose(record.pose, corrections[int64_t(r)])}}) {
      const PoseError e = pose_error(pose, *record.true_pose);
      sum->root += e.root;
      sum->body += e.body;
      sum->hands += e.hands;
      sum->translation += e.translation;
    }
    ++count;
  }
  if (count == 0) return nlohmann::json::object();
  for (PoseError* e : {&input, &refined}) {
    e->root /= double(count);
    e->body /= double(count);
    e->hands /= double(count);
    e->translation /= double(count);
  }
  return {{"input", as_json(input)}, {"refined", as_json(refined)}};
}

at::Tensor PoseRefinement::state() const { return corrections_.cpu().to(at::kDouble); }

void PoseRefinement::restore(const at::Tensor& state) {
  const int64_t rows = int64_t(frames_.size());
  // A version with per-step corrections kept their Adam moments and step counts after them.
  const int64_t with_adam = 3 * kCorrectionWidth + 1;
  TORCH_CHECK(
      state.dim() == 2 && state.size(0) == rows && (state.size(1) == kCorrectionWidth || state.size(1) == with_adam),
      "pose refinement: the checkpoint's state has shape ", state.sizes(), ", expected (", rows, ", ", kCorrectionWidth,
      ") for this dataset's training frames");
  corrections_.copy_(state.narrow(1, 0, kCorrectionWidth).to(corrections_.options()));
  keep_fits_on_host();
}

void PoseRefinement::keep_fits_on_host() {
  // A new tensor, not a copy into the old one: a fit handed out before (a field the input fit lacks is a view of its
  // row) keeps its values when the next pass moves the corrections.
  host_corrections_ = corrections_.to(at::kCPU).clone();
}

body::SmplxPose PoseRefinement::fit(int64_t frame) const {
  return corrected_pose(dataset_.frames[size_t(frame)].pose, host_corrections_[row_of(frame)]);
}

void PoseRefinement::write_fits(const std::string& path) const {
  const at::Tensor refined = (base_ + corrections_).cpu().to(at::kDouble).contiguous();
  nlohmann::json frames = nlohmann::json::object();
  for (size_t r = 0; r < frames_.size(); ++r) {
    const data::FrameRecord& record = dataset_.frames[size_t(frames_[r])];
    nlohmann::json fit;
    for (const CorrectedField& f : corrected_fields()) {
      const at::Tensor values = refined[int64_t(r)].narrow(0, f.first, 3 * f.joints);
      fit[f.name] = std::vector<double>(values.data_ptr<double>(), values.data_ptr<double>() + 3 * f.joints);
    }
    frames[record.name] = fit;
  }
  const std::string text =
      nlohmann::json{{"format", "sfgs-refined-fits"}, {"version", 1}, {"dataset", dataset_.source}, {"frames", frames}}
          .dump() +
      "\n";
  write_file_atomically(path, std::vector<unsigned char>(text.begin(), text.end()), true);
}

std::vector<int64_t> apply_refined_fits(data::Dataset& dataset, const std::string& path) {
  return apply_refined_fits(dataset, data::read_json_file(path), path);
}

std::vector<int64_t> apply_refined_fits(data::Dataset& dataset, const nlohmann::json& j, const std::string& source) {
  TORCH_CHECK(j.is_object() && j.value("format", "") == "sfgs-refined-fits" && j.contains("frames") &&
                  j.at("frames").is_object(),
              "'", source, "' is not an sfgs refined-fits file (format sfgs-refined-fits with a 'frames' object)");
  std::vector<int64_t> replaced;
  for (size_t i = 0; i < dataset.frames.size(); ++i) {
    data::FrameRecord& record = dataset.frames[i];
    if (!j.at("frames").contains(record.name)) continue;
    replaced.push_back(int64_t(i));
    const nlohmann::json& fit = j.at("frames").at(record.name);
    for (const CorrectedField& f : corrected_fields()) {
      TORCH_CHECK(fit.contains(f.name), "'", source, "': frame '", record.name, "' lacks '", f.name, "'");
      const std::string where = source + ": frame " + record.name + ": " + f.name;
      const at::Tensor value = data::json_numbers(fit.at(f.name), {3 * f.joints}, where).to(at::kFloat);
      TORCH_CHECK(value.isfinite().all().item<bool>(), where, " must be finite");
      record.pose.*(f.member) = f.joints == 1 ? value : value.view({f.joints, 3});
    }
  }
  return replaced;
}

}  // namespace sfgs::train
