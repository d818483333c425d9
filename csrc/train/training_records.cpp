#include "train/training_records.h"

#include <limits>

#include <ATen/ATen.h>

namespace sfgs::train {

TrainingRecords::TrainingRecords(int64_t gaussians, at::Device device)
    : observation_sum_(at::zeros({gaussians}, at::TensorOptions().dtype(at::kFloat).device(device))),
      footprint_minimum_(at::full_like(observation_sum_, std::numeric_limits<float>::infinity())) {}

void TrainingRecords::add(const StepOutputs& outputs) {
  const at::Tensor& skip = outputs.skip_update;
  observation_sum_ += skip.defined() ? outputs.observation * (1 - skip) : outputs.observation;
  at::minimum_out(footprint_minimum_, footprint_minimum_,
                  skip.defined() ? at::where(skip > 0.5, footprint_minimum_, outputs.footprint) : outputs.footprint);
  ++observation_steps_;
}

void TrainingRecords::save(CheckpointInfo& info) const {
  info.observation_sum = observation_sum_;
  info.observation_steps = observation_steps_;
  info.footprint_minimum = footprint_minimum_;
}

void TrainingRecords::restore(const CheckpointInfo& info) {
  observation_steps_ = info.observation_steps;
  if (info.observation_sum.defined()) observation_sum_ = info.observation_sum.to(observation_sum_.options());
  if (info.footprint_minimum.defined()) footprint_minimum_ = info.footprint_minimum.to(footprint_minimum_.options());
}

}  // namespace sfgs::train
