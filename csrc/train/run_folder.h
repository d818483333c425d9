#pragma once
// A training run's folder: config.yaml (the full configuration), checkpoint.pt (written atomically), log.jsonl
// (one JSON object per logged iteration) and what eval/render/export write. Every command that uses a trained
// avatar reads it back through here.
#include <string>

#include "data/dataset.h"
#include "model/avatar.h"
#include "train/train_config.h"

namespace sfgs::train {

struct RunFolder {
  std::string path;
  std::string config_file() const;
  std::string checkpoint_file() const;
  std::string log_file() const;
};

// The avatar the config describes, for a subject with these betas, on `device`.
model::Avatar make_avatar(const TrainConfig& config, const at::Tensor& betas, at::Device device);

// The avatar's drive for one dataset frame (time normalised over the dataset).
model::AvatarPose avatar_pose(const data::Dataset& dataset, int64_t frame, at::Device device);
// Every joint at rest, zero expression, no translation, time 0.
model::AvatarPose rest_pose(int64_t expression_count, at::Device device);
// The camera to render that frame with (identity extrinsics for poses given in camera coordinates).
Camera render_camera(const data::FrameRecord& frame);

struct TrainedAvatar {
  TrainConfig config;
  model::Avatar avatar{nullptr};
  at::Tensor betas;
  std::string dataset;  // the folder it was trained on
  int64_t iteration = 0;
};

// Reads config.yaml and checkpoint.pt of a run; errors name the missing or corrupt file.
TrainedAvatar load_trained_avatar(const RunFolder& run, at::Device device);

}  // namespace sfgs::train
