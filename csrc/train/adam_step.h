#pragma once
// Steps a torch::optim::Adam the fast way where it can: for CUDA float32 parameters, one multi-tensor kernel per
// parameter group (at::_fused_adam_, the kernel behind torch.optim.Adam(fused=True)) instead of about seven
// launches per parameter; elsewhere (CPU, other dtypes, amsgrad) the optimiser's own step. The update is LibTorch's
// Adam (L2 weight decay added to the gradient, bias corrections from the step count, parameters without a gradient
// left alone), and the state it updates is the optimiser's own (step, exp_avg, exp_avg_sq), so checkpoints and
// resumed runs are unchanged. The step counts are mirrored on the device, so a step reads nothing back.
#include <cstdint>
#include <unordered_map>

#include <ATen/core/Tensor.h>
#include <torch/optim/adam.h>

namespace sfgs::train {

// The optimiser's state of `parameter`, or null before its first step (LibTorch versions key it differently).
const torch::optim::AdamParamState* adam_state(torch::optim::Adam& optimizer, const at::Tensor& parameter);

class AdamStepper {
 public:
  // allow_fused false: always the optimiser's own step.
  explicit AdamStepper(torch::optim::Adam& optimizer, bool allow_fused = true)
      : optimizer_(optimizer), allow_fused_(allow_fused) {}
  // `skip` (optional): a 0-dim float on the device, 1 to leave this step's update out (a recorded training step
  // whose image was incomplete, StepOutputs::skip_update). The fused kernel reads it on the device, and a step it
  // skips still counts in the bias corrections' step count (one in thousands); the optimiser's own step (fused_adam
  // off) reads it back first, a host read every step, and a skipped step is not counted.
  void step(const at::Tensor& skip = at::Tensor());
  // Whether the latest step() took the fused kernel.
  bool fused() const { return fused_; }

 private:
  struct DeviceStep {
    at::Tensor count;  // float32 scalar on the parameter's device, as the fused kernel counts
    int64_t host = 0;  // the optimiser state's step it mirrors; a mismatch (a loaded state) makes it again
  };
  bool fusable() const;
  torch::optim::AdamParamState& state_of(const at::Tensor& parameter, const torch::optim::AdamOptions& options);

  torch::optim::Adam& optimizer_;
  bool allow_fused_;
  std::unordered_map<const c10::TensorImpl*, DeviceStep> device_steps_;
  bool fused_ = false;
};

}  // namespace sfgs::train
