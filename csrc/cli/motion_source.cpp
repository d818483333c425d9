#include "cli/motion_source.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <stdexcept>

#include <ATen/ATen.h>

#include "data/motions.h"
#include "train/run_folder.h"

namespace sfgs::cli {

MotionSource::MotionSource(const std::string& motion, double frames_per_second, int64_t frames,
                           const data::Dataset& trained_on)
    : name_(motion), frames_per_second_(frames_per_second) {
  if (data::is_motion_file(motion)) {
    // Only the seconds the render shows are read (a long capture's other frames never built).
    const double seconds = frames > 0 ? double(frames) / frames_per_second : std::numeric_limits<double>::infinity();
    clip_ = data::resample(data::read_motion(motion, seconds), frames_per_second);
    const auto length = static_cast<int64_t>(clip_->poses.size());
    frames_ = frames > 0 ? std::min(frames, length) : length;
    return;
  }
  // A motion from another dataset is new to the avatar: no time. Frames of the training dataset keep their replay
  // times.
  if (!data::is_motion(motion)) {
    if (!std::filesystem::is_directory(motion)) {
      std::string names;
      for (const std::string& name : data::motion_names()) names += " " + name;
      throw std::invalid_argument("motion '" + motion + "' is neither a library motion (" + names.substr(1) +
                                  "), a motion file (AMASS .npz, ExAvatar folder) nor a dataset folder");
    }
    dataset_ = data::read_dataset(motion);
    replays_ = dataset_->fingerprint() == trained_on.fingerprint();
  }
  frames_ = frames > 0 ? frames : kDefaultRenderFrames;
}

const std::string& MotionSource::note() const {
  static const std::string none;
  return clip_ ? clip_->note : none;
}

body::SmplxPose MotionSource::pose(model::Avatar& avatar, int64_t i) const {
  TORCH_CHECK(i >= 0 && i < frames_, "motion '", name_, "': frame ", i, " is not in [0, ", frames_, ")");
  if (clip_) return train::clip_pose(avatar, *clip_, i);
  if (dataset_) return dataset_->frames[size_t(i % dataset_->size())].pose;
  // The library's hand poses are absolute (data/motions.h).
  return train::hands_for_avatar(
      avatar, data::motion_pose(name_, double(i) / frames_per_second_, avatar->config().num_expression_coeffs), true);
}

model::FrameTime MotionSource::replay_time(int64_t i) const {
  if (!replays_) return std::nullopt;
  return dataset_->replay_time(i % dataset_->size());
}

}  // namespace sfgs::cli
