#pragma once
// A training run's folder: config.yaml (the full configuration), checkpoint.pt (written atomically), log.jsonl
// (one JSON object per logged iteration) and what eval/render/export write. Every command that uses a trained
// avatar reads it back through here.
#include <string>

#include "data/dataset.h"
#include "data/motion_file.h"
#include "model/avatar.h"
#include "train/train_config.h"

namespace sfgs::train {

struct RunFolder {
  std::string path;
  std::string config_file() const;
  std::string checkpoint_file() const;
  std::string log_file() const;
  // The training frames' refined fits of a run that refines its poses (PoseRefinement::write_fits).
  std::string refined_fits_file() const;
  // The fits a run's training frames started from when it was trained with start fits (TrainOptions::start_fits).
  std::string start_fits_file() const;
  // Where round `round` (1-based) of a run of several rounds trains, a run folder of its own (pose_refinement.rounds);
  // the last round is the run folder itself.
  std::string round_folder(int64_t round) const;
};

// The avatar the config describes, for a subject with these betas, on `device`.
model::Avatar make_avatar(const TrainConfig& config, const at::Tensor& betas, at::Device device);

// The avatar in dataset frame `frame`: its SMPL-X pose at its replay time (none for a new motion, dataset.h).
model::AvatarOutput pose_avatar(model::Avatar& avatar, const data::Dataset& dataset, int64_t frame);
// Frame `frame` of a motion clip as `avatar` takes it: hand poses in the avatar's convention (relative to the model's
// mean hand when the avatar adds that mean, absolute otherwise); the avatar poses it without a time.
body::SmplxPose clip_pose(model::Avatar& avatar, const data::MotionClip& clip, int64_t frame);
// `pose` with its hand poses, given absolute (`absolute_hands`: relative to a flat hand, as the motion library and
// AMASS give them) or relative to the model's mean hand, in the avatar's convention.
body::SmplxPose hands_for_avatar(const model::Avatar& avatar, body::SmplxPose pose, bool absolute_hands);
// The camera to render that frame with (identity extrinsics for poses given in camera coordinates).
Camera render_camera(const data::FrameRecord& frame);

struct TrainedAvatar {
  TrainConfig config;
  model::Avatar avatar{nullptr};
  at::Tensor betas;
  std::string dataset;  // the folder it was trained on (absolute, for runs trained by this version)
  int64_t iteration = 0;
  std::string dataset_fingerprint;  // data::Dataset::fingerprint() of it (empty for runs of the first format)
  std::string refined_fits;         // the run's refined-fits file when it refined its poses; empty otherwise
  std::string start_fits;           // the run's start-fits file when it started from other fits; empty otherwise
};

// Reads the run's checkpoint.pt and builds its avatar on `device`. The checkpoint is verified (checksums, finite
// values); errors name the file and, for damage, the tensor.
TrainedAvatar load_trained_avatar(const RunFolder& run, at::Device device);

// The dataset a trained avatar is evaluated or rendered with: `folder` when given (--data), else the one it was
// trained on; when that has moved, the error says so and how to point at it. The training frames of the dataset it
// was trained on (wherever it lies: the same fingerprint as read, or with the run's start fits applied) take the fits
// the run trained them with: its refined fits when it refined its poses, else its start fits when it had them.
// `trained_on`, when given, is set to whether the dataset is that one (a run of the first format records no
// fingerprint: its dataset counts as its own).
data::Dataset read_run_dataset(const TrainedAvatar& trained, const std::string& folder, bool* trained_on = nullptr);

// The folder a dataset was read from, absolute and normalised: what a run stores so that it can be used from any
// working directory.
std::string absolute_dataset_path(const data::Dataset& dataset);

}  // namespace sfgs::train
