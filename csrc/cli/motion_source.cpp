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

Camera look_at_camera(const Camera& lens, const std::array<double, 3>& eye, const std::array<double, 3>& target) {
  double fwd[3] = {target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]};
  const double fn = std::sqrt(fwd[0] * fwd[0] + fwd[1] * fwd[1] + fwd[2] * fwd[2]);
  TORCH_CHECK(fn > 0, "the camera distance must be positive");
  for (double& v : fwd) v /= fn;
  double right[3] = {-fwd[2], 0.0, fwd[0]};  // fwd x (0, 1, 0)
  const double rn = std::sqrt(right[0] * right[0] + right[2] * right[2]);
  TORCH_CHECK(rn > 0, "the camera looks straight up or down (its height is its whole distance)");
  right[0] /= rn;
  right[2] /= rn;
  const double down[3] = {fwd[1] * right[2] - fwd[2] * right[1], fwd[2] * right[0] - fwd[0] * right[2],
                          fwd[0] * right[1] - fwd[1] * right[0]};
  const double* rows[3] = {right, down, fwd};
  Camera cam = lens;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cam.world_to_camera[size_t(4 * r + c)] = rows[r][c];
    cam.world_to_camera[size_t(4 * r + 3)] = -(rows[r][0] * eye[0] + rows[r][1] * eye[1] + rows[r][2] * eye[2]);
  }
  return cam;
}

Camera orbit_camera(const Camera& base, const std::array<double, 3>& centre, double angle) {
  const std::array<double, 3> e = camera_centre(base);
  const double radius = std::hypot(e[0] - centre[0], e[2] - centre[2]);
  const double a = std::atan2(e[0] - centre[0], e[2] - centre[2]) + angle;
  return look_at_camera(base, {centre[0] + radius * std::sin(a), e[1], centre[2] + radius * std::cos(a)}, centre);
}

Camera camera_in_front(const Camera& lens, const std::array<double, 3>& target, double distance, double height,
                       double angle) {
  const std::array<double, 3> eye{target[0] + distance * std::sin(angle), target[1] + height,
                                  target[2] + distance * std::cos(angle)};
  return look_at_camera(lens, eye, target);
}

std::array<double, 3> centre_of(const model::AvatarOutput& posed) {
  const at::Tensor points = posed.means.detach();
  const at::Tensor c = ((std::get<0>(points.min(0)) + std::get<0>(points.max(0))) / 2).cpu().to(at::kDouble);
  return {c[0].item<double>(), c[1].item<double>(), c[2].item<double>()};
}

}  // namespace sfgs::cli
