#pragma once
// Pose refinement in training and pose fitting at test time (docs/training.md, "Imperfect fits"). Fits from pose
// estimators are off by degrees and centimetres and jitter from frame to frame; an avatar trained on them blurs to
// cover the error, and a test frame rendered with its own bad fit misses its image by the same error.
//
// A pose correction adds an axis-angle to the global orientation, the 21 body joints, the jaw and the 30 finger
// joints (kCorrectedJoints rows of 3) and a translation to a frame's fit: kCorrectionWidth numbers.
//
// PoseRefinement keeps one correction per training frame. Alignment passes at set shares of the run fit every
// frame's correction to its image and keypoints with the avatar as it is then (train/pose_fit.h, as test poses are
// fitted); between them the avatar trains on the fits as the last pass left them, without a gradient through the
// pose. Where the frames have whole-body keypoint detections the passes fit to them too (train/avatar_keypoints.h):
// the image alone lets the refined fits drift together out of the camera's frame. With config.smoothing_seconds (off
// by default), the input fits and the fits each pass leaves are smoothed over time within each sequence
// (train/fit_smoothing.h).
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>
#include <nlohmann/json.hpp>

#include "body/skeleton.h"
#include "body/wholebody_keypoints.h"
#include "data/dataset.h"
#include "model/avatar.h"
#include "train/avatar_keypoints.h"
#include "train/train_config.h"

namespace sfgs::train {

// The corrected joints in a correction's order (body/skeleton.h): the root, the body's joints, the jaw and each hand's
// joints; the eyes are not corrected.
inline constexpr int64_t kCorrectedJoints = 1 + body::kSmplxBodyJointCount + 1 + 2 * body::kHandJointCount;
inline constexpr int64_t kCorrectionWidth = 3 * kCorrectedJoints + 3;
// An alignment pass's fit ends a stage once its best loss fell by less than this share over a few L-BFGS iterations
// (PoseFitOptions::stall_share): the passes after the first start at the last one's optimum.
inline constexpr double kAlignmentStallShare = 1e-3;

// `base` with a correction (kCorrectionWidth) applied; the corrected fields are on the correction's device and carry
// its gradient, the others (eyes, expression) stay as given. A base hand pose that is undefined stays undefined.
body::SmplxPose corrected_pose(const body::SmplxPose& base, const at::Tensor& correction);

class PoseRefinement {
 public:
  // `keypoint_map` (may be null: no keypoint term) must be built for the avatar's body model; the training frames'
  // keypoint files are read here.
  PoseRefinement(const data::Dataset& dataset, const PoseRefinementConfig& config, int64_t iterations,
                 at::Device device, const body::WholeBodyKeypointMap* keypoint_map);

  // Training frame `frame`'s fit as the last alignment pass left it (the input fit before the first), on the CPU:
  // the step uploads it with the frame, so a recorded step can take it.
  body::SmplxPose fit(int64_t frame) const;
  // At an iteration of config.align_at (before its step): every training frame's correction fitted to its image with
  // `avatar` as it is (train/pose_fit.h, the run's image loss `loss`; the joints from config.align_joints_from on,
  // the global orientation from config.align_orientation_from on, the translation always).
  // `recorded`: on CUDA, the fits' evaluations as replays of recorded CUDA graphs (PoseFitOptions::recorded).
  // Returns the log entry (event "pose_alignment": the mean fitting loss before and after, the loss evaluations,
  // whether every fit's were recorded, the pass's seconds, and where the dataset has exact fits the error against them
  // before and after the pass, "pose_error_before" and "pose_error"); an empty object at other iterations.
  nlohmann::json align(int64_t iteration, model::Avatar& avatar, const LossWeights& loss, bool recorded);
  // The mean error of the refined and of the input training fits against the exact ones (FrameRecord::true_pose,
  // train/pose_fit.h PoseError) as {"input": ..., "refined": ...}; an empty object when the dataset has none.
  nlohmann::json error_against_truth() const;

  // The corrections as one (F, kCorrectionWidth) float64 tensor on the CPU, for the checkpoint; restore() takes it
  // back (its shape is checked; a checkpoint of a version with per-step corrections also held their Adam moments and
  // step counts, (F, 3 kCorrectionWidth + 1), of which the corrections are read).
  at::Tensor state() const;
  void restore(const at::Tensor& state);
  // Every training frame's refined fit, written atomically as the refined-fits JSON that apply_refined_fits reads.
  void write_fits(const std::string& path) const;

 private:
  int64_t row_of(int64_t frame) const;
  // Replaces the refined fits by their temporal smoothing (config.smoothing_seconds; nothing when 0).
  void smooth_refined_fits();
  // Copies the corrections to host_corrections_ where fit() reads them (after anything that changes them).
  void keep_fits_on_host();

  const data::Dataset& dataset_;
  PoseRefinementConfig config_;
  std::vector<int64_t> align_iterations_;  // the iterations of config.align_at
  int64_t align_joints_from_;              // alignment passes from this iteration on fit every joint
  int64_t align_orientation_from_;         // and from this one the global orientation
  std::vector<int64_t> frames_;            // training frames, by sequence and time; row r corrects frames_[r]
  std::vector<int64_t> row_;               // dataset frame -> row, -1 for frames that are not trained on
  at::Tensor base_;                        // (F, kCorrectionWidth) the input fits' corrected fields, on the device
  at::Tensor corrections_;                 // (F, kCorrectionWidth) on the device
  at::Tensor host_corrections_;            // their copy on the CPU (fit())
  std::optional<body::WholeBodyKeypointMap> keypoint_map_;  // on the device, float32; none: no keypoint term
  std::vector<FrameKeypoints> keypoints_;                   // per row; undefined for a frame without any
};

// Replaces the poses of the dataset's frames that a refined-fits document (PoseRefinement::write_fits), read from
// `source`, names by its fits; frames it does not name keep theirs. Returns the indices of the frames it replaced.
// Errors name the source, the frame and the field.
std::vector<int64_t> apply_refined_fits(data::Dataset& dataset, const nlohmann::json& fits, const std::string& source);
// The same, read from the file `path`.
std::vector<int64_t> apply_refined_fits(data::Dataset& dataset, const std::string& path);

}  // namespace sfgs::train
