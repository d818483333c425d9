#pragma once
// `sfgs fit`: SMPL-X fits of a monocular video from per-frame whole-body keypoints, in the NeuMan / ExAvatar
// layout that `sfgs train` reads. The video folder holds keypoints_whole_body/<frame>.json (133 x [x, y, score],
// COCO-WholeBody order, as DWPose writes them), the cameras (sparse/cameras.txt, dataset.json, or the image size
// alone) and optionally person masks; the fit is written as <out>/smplx_optimized/ (shape_param.json, one
// smplx_params/<frame>.json per frame in camera coordinates), with a JSON-lines log and a report. docs/fitting.md
// describes the objective, the stages and the measured accuracy.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "fit/constants.h"

namespace sfgs::fit {

// Adam steps of each stage: global orientation and translation from the torso, then the body with the shape, then
// hands, jaw and expression, then (when masks exist) everything with the silhouette term.
struct FitStageLengths {
  int64_t global = kFitGlobalIterations;
  int64_t body = kFitBodyIterations;
  int64_t detail = kFitDetailIterations;
  int64_t silhouette = kFitSilhouetteIterations;
};

struct FitOptions {
  std::string data;            // the video folder
  std::string out;             // where smplx_optimized/, fit_log.jsonl and fit_report.json go; empty: `data`.
                               // Another folder than a NeuMan-layout `data` becomes a dataset of the fits: the
                               // video's other entries are linked into it, so `sfgs train --data OUT` reads it
  std::string body_model;      // SMPL-X-layout .npz; empty: the built-in procedural body
  std::string device = "cpu";  // cpu or cuda
  // LibTorch's intra-op threads for a CPU fit. Its tensors are small (a few hundred points per frame): more threads
  // save little and, on a machine whose cores are busy, wait on each other an order of magnitude longer.
  int64_t threads = kFitCpuThreads;
  std::string truth;  // exact fits to measure against (smplx_optimized layout); empty: <data>/ground_truth if any
  double focal = 0;   // pixels, replacing the dataset's (0: the dataset's, or max(width, height))
  bool betas_from_data = false;  // keep the dataset's shape (smplx_optimized/shape_param.json, dataset.json)
  // Start from the folder's own fits (smplx_optimized/, e.g. a pose estimator's) instead of the closed-form start.
  bool start_from_data = false;
  bool use_masks = true;  // the silhouette stage, where masks exist
  FitStageLengths iterations;
  int64_t log_every = kFitLogEvery;
  bool overwrite = false;  // replace an existing <out>/smplx_optimized
  bool quiet = false;      // no progress lines
};

// Errors of the fit against exact fits, over the frames both have, in millimetres.
struct FitAccuracy {
  std::string reference;  // where the exact fits came from
  int64_t frames = 0;
  double mpjpe_mm = 0;           // body joints 0..21, both skeletons' pelvis moved to the origin
  double mpjpe_absolute_mm = 0;  // body joints in camera coordinates as fitted
  double pa_mpjpe_mm = 0;        // body joints after the best similarity transform per frame
  double hand_mpjpe_mm = 0;      // finger joints, each hand's wrist moved to the origin
  double vertex_error_mm = 0;    // every vertex, pelvis-aligned
  double vertex_error_absolute_mm = 0;
  double depth_error_mm = 0;  // mean |z| error of the pelvis: the monocular scale / depth ambiguity
};

struct FitStageSummary {
  std::string name;
  int64_t iterations = 0;
  double seconds = 0;
  double loss = 0;  // at the stage's last step
};

struct FitReport {
  int64_t frames = 0;
  std::string camera_source;
  bool silhouette = false;  // whether the silhouette stage ran
  std::vector<FitStageSummary> stages;
  double seconds = 0;  // the whole fit, reading and writing included
  std::optional<FitAccuracy> accuracy;
  bool trainable_dataset = false;  // the output folder is a dataset `sfgs train --data` reads with these fits
};

// Reads, fits, writes; errors name the file and what was expected. Progress goes to stdout unless quiet.
FitReport run_fit(const FitOptions& options);

}  // namespace sfgs::fit
