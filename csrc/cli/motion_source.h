#pragma once
// What `sfgs render` and `sfgs export --web` play, read one way for both: a motion (a library motion, a dataset's
// frames or a motion file; docs/motions.md) posed frame by frame on a trained avatar, and the cameras that
// `render --camera` places around it.
#include <array>
#include <cstdint>
#include <optional>
#include <string>

#include "data/dataset.h"
#include "data/motion_file.h"
#include "model/avatar.h"
#include "ops/splat/splat.h"

namespace sfgs::cli {

// The frame rate of the video, and of library motions sampled for it (the cameras: animate/camera_placement.h).
inline constexpr double kRenderFramesPerSecond = 24.0;
// Frames of a library or dataset motion when none are asked for (a motion file plays whole).
inline constexpr int64_t kDefaultRenderFrames = 48;

class MotionSource {
 public:
  // `motion`: a library motion's name, a dataset folder or a motion file (data::is_motion_file), sampled at
  // `frames_per_second`; `frames` > 0 caps a motion file and sets the length of the others (0: the whole file, or
  // kDefaultRenderFrames). `trained_on` is the avatar's training dataset: its own frames replay at their times.
  MotionSource(const std::string& motion, double frames_per_second, int64_t frames, const data::Dataset& trained_on);

  int64_t frame_count() const { return frames_; }
  bool is_file() const { return clip_.has_value(); }
  const std::string& note() const;  // what the motion file's reader filled in or left out; empty when nothing

  // Frame i's pose as `avatar` takes it (hands in its convention).
  body::SmplxPose pose(model::Avatar& avatar, int64_t i) const;
  // Frame i's replay time: a frame of the training dataset keeps its time (model/frame_time.h); anything else is a
  // new motion, without one.
  model::FrameTime replay_time(int64_t i) const;

 private:
  std::string name_;
  double frames_per_second_;
  int64_t frames_ = 0;
  std::optional<data::MotionClip> clip_;
  std::optional<data::Dataset> dataset_;
  bool replays_ = false;  // dataset_ is the training dataset
};

}  // namespace sfgs::cli
