#pragma once
// What training learns about its views of the avatar besides the parameters, step by step, for rendering it once
// trained: how squarely each Gaussian was seen (the observation record, model/observation_prior.h) and how finely (the
// sampling record, model/sampling_filter.h). Kept on the device while training, carried by the checkpoint;
// CheckpointReader::load_avatar gives a trained avatar both. While training, the avatar itself carries neither (an
// avatar with them renders differently in eval mode, so a resumed run's alignment passes would differ from those of
// a run never paused).
#include <cstdint>

#include <ATen/core/Tensor.h>

#include "train/checkpoint.h"
#include "train/training_step.h"

namespace sfgs::train {

class TrainingRecords {
 public:
  TrainingRecords(int64_t gaussians, at::Device device);
  // A step's records. A step the optimiser leaves out (StepOutputs::skip_update 1: an incomplete image) adds nothing,
  // and still counts, one in thousands. No host read.
  void add(const StepOutputs& outputs);
  // Into the checkpoint's info, and back from a checkpoint's (a checkpoint without them leaves these empty).
  void save(CheckpointInfo& info) const;
  void restore(const CheckpointInfo& info);

 private:
  at::Tensor observation_sum_;  // (N) the sum over steps of how squarely each step's frame saw each Gaussian
  int64_t observation_steps_ = 0;
  at::Tensor footprint_minimum_;  // (N) the smallest world footprint of a pixel any step had of each Gaussian
};

}  // namespace sfgs::train
