#include "train/training_parts.h"

#include <cstdio>
#include <utility>

#include <c10/util/Exception.h>

#include "common/atomic_file.h"
#include "train/avatar_keypoints.h"
#include "train/pose_refinement.h"
#include "train/training_records.h"

namespace sfgs::train {
namespace {

// Pose refinement (train/pose_refinement.h): alignment passes before the steps config.align_at names, each step
// trained on its frame's fit as the last pass left it, the fits' error against exact ones in validations, the
// corrections in the checkpoint and the refined fits beside it.
class PoseRefinementPart : public TrainingPart {
 public:
  PoseRefinementPart(const data::Dataset& dataset, const TrainConfig& config, at::Device device)
      : loss_(config.loss), recorded_(config.schedule.cuda_graphs) {
    const bool keypoints =
        config.pose_refinement.keypoint_weight > 0 && dataset.frames_with_keypoints(data::Split::kTrain) > 0;
    const std::optional<body::WholeBodyKeypointMap> map =
        keypoints ? std::optional(body_keypoint_map(config.body.smplx)) : std::nullopt;
    refinement_ = std::make_unique<PoseRefinement>(dataset, config.pose_refinement, config.schedule.iterations, device,
                                                   map ? &*map : nullptr);
  }

  nlohmann::json before_step(int64_t iteration, model::Avatar& avatar) override {
    return refinement_->align(iteration, avatar, loss_, recorded_);
  }
  void prepare_step(int64_t frame, StepData& data) const override { data.pose = refinement_->fit(frame); }
  void describe_validation(nlohmann::json& entry) const override {
    const nlohmann::json error = refinement_->error_against_truth();
    if (!error.empty()) entry["pose_error"] = error;
  }
  void save(CheckpointInfo& info) const override { info.pose_refinement = refinement_->state(); }
  void restore(const CheckpointInfo& info, const std::string& checkpoint_file) override {
    TORCH_CHECK(info.pose_refinement.defined(), "checkpoint '", checkpoint_file,
                "' holds no pose refinement state, but the run's config refines poses");
    refinement_->restore(info.pose_refinement);
  }
  void write_beside_checkpoint(const RunFolder& run) const override {
    refinement_->write_fits(run.refined_fits_file());
  }

 private:
  LossWeights loss_;
  bool recorded_;
  std::unique_ptr<PoseRefinement> refinement_;
};

// The observation and sampling records (train/training_records.h), collected every step and carried by the
// checkpoint.
class RecordsPart : public TrainingPart {
 public:
  RecordsPart(int64_t gaussians, at::Device device) : records_(gaussians, device) {}
  void after_step(const StepOutputs& outputs) override { records_.add(outputs); }
  void save(CheckpointInfo& info) const override { records_.save(info); }
  void restore(const CheckpointInfo& info, const std::string& /*checkpoint_file*/) override { records_.restore(info); }

 private:
  TrainingRecords records_;
};

class StartFitsCopy : public TrainingPart {
 public:
  explicit StartFitsCopy(std::optional<std::vector<unsigned char>> bytes) : bytes_(std::move(bytes)) {}
  void write_beside_checkpoint(const RunFolder& run) const override {
    if (bytes_)
      write_file_atomically(run.start_fits_file(), *bytes_, true);
    else
      std::remove(run.start_fits_file().c_str());
  }

 private:
  std::optional<std::vector<unsigned char>> bytes_;
};

}  // namespace

std::vector<std::unique_ptr<TrainingPart>> make_training_parts(const data::Dataset& dataset, const TrainConfig& config,
                                                               int64_t gaussians, at::Device device) {
  std::vector<std::unique_ptr<TrainingPart>> parts;
  if (config.pose_refinement.enabled) parts.push_back(std::make_unique<PoseRefinementPart>(dataset, config, device));
  parts.push_back(std::make_unique<RecordsPart>(gaussians, device));
  return parts;
}

std::unique_ptr<TrainingPart> make_start_fits_copy(std::optional<std::vector<unsigned char>> bytes) {
  return std::make_unique<StartFitsCopy>(std::move(bytes));
}

}  // namespace sfgs::train
