#pragma once
// The parts of training that plug into TrainingSession (internal to the trainer). The session steps the avatar on one
// training frame at a time; a part adds to that loop without the session knowing what it does: pose refinement
// aligns the fits between steps and hands each step its frame's refined fit, the training records collect what each
// step saw, and the start-fits copy keeps the fits a run started from beside its checkpoint. Each hook has a default
// that does nothing, so a part names only the moments it acts at; the session calls the parts in the order it holds
// them.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "model/avatar.h"
#include "train/checkpoint.h"
#include "train/run_folder.h"
#include "train/train_config.h"
#include "train/training_step.h"

namespace sfgs::train {

class TrainingPart {
 public:
  virtual ~TrainingPart() = default;
  // Before iteration `iteration`'s step, with the avatar as the steps left it: the log entry of what the part did
  // there, or an empty object.
  virtual nlohmann::json before_step(int64_t /*iteration*/, model::Avatar& /*avatar*/) { return {}; }
  // What the step on training frame `frame` trains on: the part may replace fields of `data`.
  virtual void prepare_step(int64_t /*frame*/, StepData& /*data*/) const {}
  // After the optimiser took the step (no host read: a GPU step is still running).
  virtual void after_step(const StepOutputs& /*outputs*/) {}
  // Fields the part adds to a validation's log entry.
  virtual void describe_validation(nlohmann::json& /*entry*/) const {}
  // The part's state into a checkpoint's info, and back from a checkpoint's on resume (`checkpoint_file` names it in
  // errors).
  virtual void save(CheckpointInfo& /*info*/) const {}
  virtual void restore(const CheckpointInfo& /*info*/, const std::string& /*checkpoint_file*/) {}
  // Once the checkpoint is written: the files the part keeps beside it, so that they always belong to it.
  virtual void write_beside_checkpoint(const RunFolder& /*run*/) const {}
};

// The parts a run's config asks for, in the order the session calls them: pose refinement (config.pose_refinement
// enabled; with its keypoint term where the training frames have keypoints), then the training records of `gaussians`
// Gaussians.
std::vector<std::unique_ptr<TrainingPart>> make_training_parts(const data::Dataset& dataset, const TrainConfig& config,
                                                               int64_t gaussians, at::Device device);

// Keeps the bytes of the start-fits file a run trains from (none: the dataset's own fits) beside every checkpoint
// (RunFolder::start_fits_file; removed there when none).
std::unique_ptr<TrainingPart> make_start_fits_copy(std::optional<std::vector<unsigned char>> bytes);

}  // namespace sfgs::train
