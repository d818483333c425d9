#pragma once
// One loss evaluation of a pose fit (train/pose_fit.h): the avatar posed at a frame's fit plus a correction, rendered,
// compared with the frame's image, mask and keypoints, and the loss's gradient to the correction. PoseFitter runs
// hundreds per frame, each one a host decision of L-BFGS's line search apart: on CUDA, PoseFitGraphs records the
// evaluation of each kind of stage once as a CUDA graph and replays it (one launch and one read of the loss and
// gradient, instead of a thousand launches paced by the host); elsewhere, or when a recording fails, the same loss runs
// eagerly.
//
// A frame's pose-independent attributes (the planes, heads and observation prior at its time) are made once per fit
// (Avatar::attributes), not per evaluation: the recorded evaluations read them from buffers the frame is copied into.
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>

#include <ATen/core/Tensor.h>

#include "body/smplx_pose.h"
#include "body/wholebody_keypoints.h"
#include "common/device_graph.h"
#include "model/avatar.h"
#include "model/inference_cache.h"
#include "ops/splat/camera_frame.h"
#include "ops/splat/growing_budget.h"
#include "ops/splat/splat.h"
#include "train/avatar_keypoints.h"
#include "train/losses.h"

namespace sfgs::train {

// What one stage of a fit compares the posed avatar with, on the avatar's device.
struct FitFrame {
  body::SmplxPose pose;  // the frame's fit, which the correction adds to
  model::CanonicalAttributes attributes;
  bool has_time = false;     // whether the attributes are a replayed frame's (its time branch)
  CameraFrame camera_frame;  // the camera's placement, applied on the device; undefined: `camera` is used as is
  Camera camera;             // the stage's camera (at the origin when camera_frame is defined)
  at::Tensor image;          // (H, W, 3) on white outside the person, at the stage's resolution
  at::Tensor mask;           // (H, W) person mask; undefined: the whole image, no silhouette
  FrameKeypoints keypoints;  // undefined: no keypoint term
  // The share of the whole image's pixels that `image` covers when it is a crop around the person. The image terms
  // are means over the crop, scaled by it to the whole image's means (the pixels left out match: white, no alpha), so a
  // crop keeps the objective and its balance with the keypoint term.
  double pixel_share = 1;
};

// A stage's loss: `run_loss` the run's image loss inside the person plus a light silhouette (the fine stage), else
// the image's L1 plus the silhouette, both times the frame's pixel share; plus keypoint_weight times the keypoint
// reprojection error where the frame has detections and a map is given.
class FitLoss {
 public:
  // `gradient`: what the correction's gradient flows through (model::PoseGradient).
  FitLoss(const ImageLoss& image_loss, const body::WholeBodyKeypointMap* keypoint_map, double keypoint_weight,
          model::PoseGradient gradient = model::PoseGradient::kWhole);
  // A 0-dim loss with a gradient to `correction` (kCorrectionWidth, on the avatar's device); with a budget (a
  // recorded evaluation), the render's buffers sized from it (splat.h).
  at::Tensor operator()(model::Avatar& avatar, const FitFrame& frame, const at::Tensor& correction, bool run_loss,
                        const BinningBudget* budget = nullptr) const;

 private:
  // The stage's image and silhouette terms, as means over the frame's image.
  at::Tensor image_terms(const RenderResult& render, const FitFrame& frame, bool run_loss) const;

  const ImageLoss& image_loss_;
  const body::WholeBodyKeypointMap* keypoint_map_;
  double keypoint_weight_;
  model::PoseGradient gradient_;
};

// The loss and its gradient (CPU float32, kCorrectionWidth) at one correction.
struct FitEvaluation {
  double loss = 0;
  at::Tensor gradient;
};

// The stages' evaluations recorded as CUDA graphs (common/device_graph.h), one per kind of stage (run_loss, image
// size, focal lengths and pixel share, pose layout, time, mask, keypoints), in one memory pool: the camera's placement
// and principal point are read from a buffer (with_centred_principal_point), so the crops of one size share a graph.
// The splatting's buffers are sized from a budget (ops/splat/growing_budget.h); each replay's counts are read with its
// loss, and a replay beyond the budget grows it, records again and evaluates again, so every returned loss is of a
// whole image.
class PoseFitGraphs {
 public:
  PoseFitGraphs(model::Avatar avatar, const FitLoss& loss, at::Device device);
  ~PoseFitGraphs();
  PoseFitGraphs(const PoseFitGraphs&) = delete;
  PoseFitGraphs& operator=(const PoseFitGraphs&) = delete;

  // Copies `frame` into the buffers of its kind, which evaluate() then reads: once per frame and stage.
  void load(const FitFrame& frame, bool run_loss);
  // The loaded frame's loss and gradient at `correction` (kCorrectionWidth, any device). Throws GraphCaptureError
  // when the evaluation cannot be recorded (nothing of it ran; the caller evaluates eagerly).
  FitEvaluation evaluate(const at::Tensor& correction);
  int64_t captures() const { return captures_; }
  const model::Avatar& avatar() const { return avatar_; }

 private:
  struct Kind;
  at::Tensor run_budgeted(Kind& kind);
  void capture(Kind& kind);
  void drop_graphs();

  model::Avatar avatar_;
  const FitLoss& loss_;
  at::Device device_;
  std::map<std::string, std::unique_ptr<Kind>> kinds_;
  Kind* loaded_ = nullptr;
  GrowingBudget budget_;
  int64_t captures_ = 0;
};

}  // namespace sfgs::train
