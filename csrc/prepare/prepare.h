#pragma once
// `sfgs prepare`: a video of one person (or a folder of its frames) to a dataset `sfgs train --data` reads
// (docs/prepare.md). Each frame's person is tracked (detect/pose_tracker.h); the frame, its person mask and its
// whole-body keypoints are written in the NeuMan / ExAvatar layout with a pinhole camera, then `sfgs fit` fits SMPL-X
// to the keypoints and masks. The dataset is built in a temporary folder and moved into place once complete.
#include <cstdint>
#include <functional>
#include <optional>
#include <string>

#include <ATen/core/Tensor.h>

#include "detect/pose_tracker.h"
#include "fit/fit.h"

namespace sfgs::prepare {

// The frames of a video in order: the next frame (H, W, 3) float32 in [0, 1] on the CPU, or none at the end.
using FrameSource = std::function<std::optional<at::Tensor>()>;

// A folder's images (.png, .jpg, .jpeg; read in name order), as a frame source; errors name the folder.
FrameSource image_folder(const std::string& folder);

// `source`'s frames decoded on a thread of its own, up to `depth` frames ahead of the caller, so that decoding overlaps
// detection. An error of the source comes to the caller at the frame where it happened. The source is called from
// that thread only.
FrameSource read_ahead(FrameSource source, size_t depth);

struct PrepareOptions {
  std::string out;             // the dataset folder
  std::string device = "cpu";  // where the networks and the fit run: cpu or cuda
  double focal = 0;            // pixels; 0: from focal_35mm, else max(width, height) (53 degrees along the longer side)
  double focal_35mm = 0;       // the video's 35 mm-equivalent focal length (video_metadata.h); 0: none stated
  detect::PoseModel model = detect::PoseModel::kFull;
  bool smooth = true;             // the body's landmarks smoothed over the frames (one-euro filters, as MediaPipe)
  int64_t max_frames = 0;         // 0: every frame
  double frames_per_second = 30;  // the frames' rate (a video's own), for smoothing the landmarks over time
  bool fit = true;                // run `sfgs fit` on the result (the dataset needs fits to train)
  fit::FitOptions fit_options;    // data, out, device, focal and overwrite are set from these options
  bool overwrite = false;         // replace an existing dataset folder
  bool quiet = false;             // no progress
};

struct PrepareReport {
  int64_t frames = 0;               // frames read
  int64_t frames_with_person = 0;   // frames written (a frame without a person is left out)
  int64_t frames_with_several = 0;  // frames in which the detector saw several people (the largest is followed)
  int64_t width = 0, height = 0;
  double focal = 0;
  std::string focal_source;      // "given", "metadata" (the video's 35 mm-equivalent focal length) or "default"
  double detection_seconds = 0;  // reading and tracking, writing included
  std::optional<fit::FitReport> fit;
};

// Errors: unreadable input, frames of different sizes, no person in any frame, an existing `out` without overwrite.
PrepareReport prepare_dataset(const FrameSource& frames, const PrepareOptions& options);

}  // namespace sfgs::prepare
