#pragma once
// One training step's device work apart from the optimiser: the drawn frame's target, the avatar posed at its fit,
// the render, the losses and the backward. Its inputs live in buffers that keep their addresses from step to step
// (StepInputs), and it reads nothing back to the host, so a CUDA step can be recorded once as a graph and replayed
// (train/step_graphs.h); the same code runs eagerly on the CPU or with graphs switched off.
#include <array>
#include <optional>
#include <string>

#include <ATen/core/Tensor.h>

#include "body/smplx_pose.h"
#include "model/avatar.h"
#include "ops/splat/camera_frame.h"
#include "ops/splat/splat.h"
#include "train/losses.h"

namespace sfgs::train {

// One step's data as the trainer draws it, on the host.
struct StepData {
  at::Tensor frame;      // (H, W, 4) uint8: the image's RGB and its mask (page-locked when the frame is cached)
  body::SmplxPose pose;  // the frame's fit (checked when the dataset was read), on the CPU
  Camera camera;         // the frame's render camera
  std::array<float, 3> background{};  // the step's random background colour
  std::optional<double> time;         // the frame's time; none: the step leaves the time branch out
  bool lpips = true;                  // whether the step measures LPIPS (loss.lpips_every)
};

// What a step's recorded work depends on beyond the values it reads from StepInputs: steps of one kind can share a
// graph. The camera's intrinsics and image size are baked into the splatting's launches; its pose is not (a camera
// away from the origin moves the Gaussians into its frame on the device).
std::string step_kind(const StepData& data);

// The device buffers of one kind of step, refilled by one upload per step.
class StepInputs {
 public:
  StepInputs(const StepData& like, at::Device device);
  // Copies `data` (of this kind; its time, if any, in [-1, 1]) into the buffers: asynchronously on CUDA (page-locked
  // staging), so the host goes on.
  void upload(const StepData& data);
  // World points (N, 3), directions (N, 3) and covariances (N, 6) in the uploaded camera's frame, differentiable;
  // the values themselves when the kind's camera sits at the origin. Rendered with `camera` they give the image
  // the drawn camera gives the world.
  at::Tensor points_to_camera(const at::Tensor& points) const;
  at::Tensor directions_to_camera(const at::Tensor& directions) const;
  at::Tensor covariances_to_camera(const at::Tensor& covariances) const;

  at::Tensor frame;          // (H, W, 4) uint8
  at::Tensor background;     // (3) float32
  CameraFrame camera_frame;  // a camera away from the origin: its placement (else undefined)
  at::Tensor time;           // () float32; undefined when the kind has no time
  body::SmplxPose pose;      // float32 views of one buffer, in the kind's layout
  Camera camera;             // the kind's camera at the origin (the intrinsics and image size of its steps)
  // A recorded step's splatting budget (splat.h), set by StepGraphs around the step; none: the op reads its count.
  std::optional<BinningBudget> budget;

 private:
  std::string kind_;   // step_kind of the steps these buffers take
  at::Tensor values_;  // pose values, then background, world_to_camera and time: one upload
  int64_t pose_values_ = 0;
};

// What a step leaves on the device for the trainer: the loss terms (watched for divergence), the image's PSNR against
// the target, how squarely the frame saw each Gaussian (the observation record, model/observation_prior.h) and how
// finely (the sampling record, model/sampling_filter.h).
struct StepOutputs {
  LossTerms terms;
  at::Tensor psnr;
  at::Tensor observation;  // (N)
  at::Tensor footprint;  // (N) the world length of a pixel at each Gaussian in view, +inf elsewhere (sampling_filter.h)
  // A recorded step's: 0-dim float on the device, 1 where its splatting went beyond the budget (an incomplete
  // image: the optimiser leaves the step out), else 0. Undefined for eager steps, which are always whole.
  at::Tensor skip_update;
};

class TrainingStep {
 public:
  TrainingStep(model::Avatar avatar, const ImageLoss& image_loss, const Regularisers& regularisers);
  // Forward, losses and backward of one step on `inputs` (posed at inputs.pose). The parameters' gradients are set,
  // not accumulated: those the step does not reach (the time planes in a step without a time) are left undefined.
  StepOutputs run(const StepInputs& inputs, bool lpips);

 private:
  model::Avatar avatar_;
  const ImageLoss& image_loss_;
  const Regularisers& regularisers_;
};

}  // namespace sfgs::train
