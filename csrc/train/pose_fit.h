#pragma once
// Fitting a frame's pose to its image with the avatar frozen (docs/training.md, "Imperfect fits"): the NeuMan
// protocol's test-time pose fitting (fit_poses) and the alignment of the training frames' fits in pose refinement
// (PoseRefinement::align). Only the pose correction (train/pose_refinement.h) moves.
//
// Three stages, each a fresh L-BFGS with a strong-Wolfe line search over its share of the loss evaluations (a render
// and its gradient; kPoseFit*Share, common/constants.h): the joints' corrections couple along the kinematic chain,
// which a quasi-Newton model resolves and a per-number Adam does not (docs/archive/results-history.md, "L-BFGS"):
//  1. coarse: the placement alone (the translation, and the global orientation unless PoseFitOptions holds it),
//     against the image and the person mask at
//     1/kPoseFitCoarseDownsample of the resolution (a wide basin: centimetres of depth and lateral error);
//  2. middle: every corrected field at 1/kPoseFitMiddleDownsample, the same loss;
//  3. fine: every corrected field at full resolution, against the run's image loss inside the person (the
//     evaluation protocol's view) plus a lighter silhouette term.
// With a person mask, every stage compares a crop around the person (person_crop), its image terms scaled to the
// whole image's means: the same objective without the white rest of the image.
// When the frame has whole-body keypoint detections (FrameRecord::keypoints_path) and the fitter a keypoint map, every
// stage also minimises their robust reprojection error (train/avatar_keypoints.h), weighted by keypoint_weight: they
// pull a far start into the image's basin and pin the placement a frontal image sees poorly.
// Each stage keeps its best iterate, and the fit returns its start when nothing beat it on the fine loss: a fit is
// never worse than its start on the loss it minimises. L-BFGS runs on the host; each evaluation is the stage's loss and
// gradient on the avatar's device, on CUDA a replay of a recorded graph (train/pose_fit_evaluation.h).
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include <ATen/core/Tensor.h>

#include "body/wholebody_keypoints.h"
#include "train/constants.h"
#include "data/dataset.h"
#include "model/avatar.h"
#include "ops/splat/splat.h"
#include "train/avatar_keypoints.h"
#include "train/losses.h"
#include "train/pose_fit_evaluation.h"
#include "train/pose_refinement.h"
#include "train/train_config.h"

namespace sfgs::train {

struct PoseFitOptions {
  int64_t iterations = kPoseFitIterations;  // loss evaluations per frame, over the three stages
  LossWeights loss;                         // the image loss of the fine stage (regularisers are not used)
  // What moves besides the translation (the alignment of training fits: an avatar still learning is sharp enough to
  // place the body before it can turn it or pose its joints). The coarse stage never fits the joints.
  bool fit_orientation = true;
  bool fit_joints = true;
  // Weight of the keypoint reprojection term where the target has detections; 0: the image alone.
  double keypoint_weight = kPoseFitKeypointWeight;
  // On CUDA, each kind of stage's evaluation recorded once as a CUDA graph and replayed (train/pose_fit_evaluation.h);
  // false: every evaluation eager (the schedule's cuda_graphs in pose refinement).
  bool recorded = true;
  // What the correction's gradient flows through (model::PoseGradient): the whole avatar where each frame is fitted
  // once and accuracy is the point (test-time fitting), the skeleton where a training fits every frame at each of
  // its alignment passes (PoseRefinement).
  model::PoseGradient gradient = model::PoseGradient::kWhole;
  // A stage ends once its best loss fell by less than this share over its last kPoseFitStallEvaluations evaluations:
  // a frame that starts at its optimum (an alignment pass after another) spends few. 0: every stage spends its share.
  double stall_share = 0;
};

// The window of PoseFitOptions::stall_share: a few L-BFGS iterations with their line searches.
inline constexpr int64_t kPoseFitStallEvaluations = 10;

// What a frame's pose is fitted to: its image on white outside the person, the person mask, its render camera and
// its time on the avatar's time axis, on the avatar's device.
struct PoseFitTarget {
  at::Tensor image;  // (H, W, 3)
  at::Tensor mask;   // (H, W)
  Camera camera;
  std::optional<double> time;
  FrameKeypoints keypoints;  // the frame's detections; undefined when it has none or they were not asked for
};
// `with_keypoints`: read the frame's keypoint file, when it has one (only a fit with a keypoint term reads it).
PoseFitTarget pose_fit_target(const data::Dataset& dataset, int64_t frame, at::Device device, bool with_keypoints);
// The detections of `record`'s keypoint file on `device`, in the pixels of its render camera; undefined when the frame
// has no keypoint file.
FrameKeypoints record_keypoints(const data::FrameRecord& record, at::Device device);

// A rectangle of an image's pixels: columns [x, x + width), rows [y, y + height).
struct PixelBox {
  int64_t x = 0, y = 0, width = 0, height = 0;
};
// The part of a target's image a fit compares, from its (H, W) person mask: the box of the person's pixels widened by
// kPoseFitCropMargin of its larger side each way, its sides rounded up to multiples of kPoseFitCropStep (an axis the
// rounded box would cover is kept whole), its origin on the coarsest stage's pixel grid so that every stage's crop is
// the crop of its downsampled image. The whole image when the mask holds no person.
PixelBox person_crop(const at::Tensor& mask);
// The fine stage's view of `target` at `pose`: the fit on the target's device, the avatar's pose-independent
// attributes at the target's time (made here, once for all of a fit's evaluations), the target's keypoints, and its
// image, mask and camera on the person's crop (person_crop) with the crop's pixel share; the whole image where
// `cropped` is false or the target has no mask.
FitFrame fit_frame(model::Avatar& avatar, const body::SmplxPose& pose, const PoseFitTarget& target, bool cropped);

struct PoseFitResult {
  at::Tensor correction;            // (kCorrectionWidth) float32 on the CPU
  double start_loss = 0, loss = 0;  // the fine loss at the start and at the result (never above start_loss)
  int64_t evaluations = 0;          // loss evaluations run (the start's included)
  bool recorded = false;            // whether they were replays of recorded CUDA graphs
};

// Fits the correction of `pose` (from `start`, a (kCorrectionWidth) correction on any device) to `target`. One fitter
// serves many frames of one avatar: the image loss (LPIPS) loads once, and on CUDA the recorded evaluations are kept
// from frame to frame while the avatar holds still.
class PoseFitter {
 public:
  // `keypoint_map` (may be null: no keypoint term) must be built for the avatar's body model.
  PoseFitter(const PoseFitOptions& options, at::Device device, const body::WholeBodyKeypointMap* keypoint_map);
  ~PoseFitter();
  PoseFitter(const PoseFitter&) = delete;
  PoseFitter& operator=(const PoseFitter&) = delete;
  // The avatar must hold still between the fits of one fitter (its recorded evaluations read its parameters).
  PoseFitResult fit(model::Avatar& avatar, const body::SmplxPose& pose, const PoseFitTarget& target,
                    const at::Tensor& start);
  // Whether fit() adds the keypoint term to a target with detections (a map was given and the weight is positive).
  bool uses_keypoints() const { return keypoint_map_.has_value(); }

 private:
  PoseFitOptions options_;
  ImageLoss loss_;
  std::optional<body::WholeBodyKeypointMap> keypoint_map_;  // on the device, float32
  std::unique_ptr<FitLoss> fit_loss_;
  std::unique_ptr<PoseFitGraphs> graphs_;  // made at the first recorded fit of an avatar
  bool recording_failed_ = false;          // a recording failed: this fitter evaluates eagerly from then on
};

// How far a fit lies from the truth: the mean geodesic angle (degrees) of the global orientation, of the 21 body
// joints and of the 30 finger joints (when both fits have hands), and the translation's distance (centimetres).
struct PoseError {
  double root = 0, body = 0, hands = 0, translation = 0;
};
PoseError pose_error(const body::SmplxPose& fit, const body::SmplxPose& truth);
std::string to_string(const PoseError& e);

// `dataset` with the poses of `split` fitted to their images with the avatar frozen: the same schedule for every
// frame, from its given fit, anchored on the frames' keypoint detections where they have them and `keypoint_map` is
// given. `progress` prints one line per frame.
data::Dataset fit_poses(const data::Dataset& dataset, data::Split split, model::Avatar& avatar,
                        const PoseFitOptions& options, const body::WholeBodyKeypointMap* keypoint_map, bool progress);

}  // namespace sfgs::train
