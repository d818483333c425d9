#pragma once
// Evaluating and exporting a trained avatar: the ExAvatar/SFGS protocol over a dataset split, and the posed or
// canonical Gaussians as a standard 3D Gaussian Splatting .ply.
#include <string>
#include <vector>

#include "data/dataset.h"
#include "metrics/evaluation.h"
#include "model/avatar.h"
#include "train/region_metrics.h"

namespace sfgs::train {

// A person's pixel is covered where the render's alpha reaches this; below it the white background shows through
// (holes and dots between Gaussians, as in a render finer than the training's; model/sampling_filter.h).
inline constexpr double kCoveredAlpha = 0.95;

struct AvatarEvaluation {
  metrics::EvaluationSummary summary;
  std::vector<std::string> frame_names;
  std::vector<metrics::FrameMetrics> frames;
  // Avatar forward + rasterisation a frame, on the device the avatar is on: the median over the frames, and the first
  // frame's, which on CUDA also records the frame's graph (animate::Animator).
  double render_milliseconds = 0;
  double first_render_milliseconds = 0;
  // Per sequence (a motion of a synthetic video), in order of appearance, with the share of the person the training
  // never or rarely showed where the dataset has ground-truth geometry.
  std::vector<GroupScore> motions;
  std::vector<GroupScore> regions;  // body, face, hands, seen, unseen; empty without ground-truth geometry
  // Of the person's pixels (the evaluation mask, over all frames), the share the render leaves uncovered (alpha below
  // kCoveredAlpha); none where the masks hold no person.
  std::optional<double> uncovered_share;
};

// Renders every frame of the split on white and scores it against the ground truth composited on white outside the
// evaluation mask (per-frame metrics averaged; tc-LPIPS within each sequence), also per sequence and, where the
// dataset has ground-truth geometry, per region (region_metrics.h). `save_folder` (may be empty) receives the
// rendered PNGs.
AvatarEvaluation evaluate_avatar(const data::Dataset& dataset, data::Split split, model::Avatar& avatar,
                                 const metrics::EvaluationOptions& options, const std::string& save_folder,
                                 bool overwrite);

}  // namespace sfgs::train
