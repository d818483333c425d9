// The training step's GPU parts: the fused Adam step (train/adam_step.h) against LibTorch's own Adam::step over
// several steps, two parameter groups with their own learning rates, weight decay, and a parameter that a step leaves
// without a gradient. Skips without a CUDA device.
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/cuda.h>
#include <torch/optim/adam.h>

#include "test_avatar_utils.h"
#include "train/adam_step.h"
#include "train/training_session.h"

namespace sfgs::testing {
namespace {

std::vector<at::Tensor> parameters_like(const std::vector<at::Tensor>& shapes) {
  std::vector<at::Tensor> out;
  for (const at::Tensor& t : shapes) out.push_back(t.clone().requires_grad_(true));
  return out;
}

std::unique_ptr<torch::optim::Adam> two_group_adam(const std::vector<at::Tensor>& p) {
  std::vector<torch::optim::OptimizerParamGroup> groups;
  groups.emplace_back(std::vector<at::Tensor>{p[0], p[1]},
                      std::make_unique<torch::optim::AdamOptions>(torch::optim::AdamOptions(1e-2).eps(1e-15)));
  groups.emplace_back(std::vector<at::Tensor>{p[2]}, std::make_unique<torch::optim::AdamOptions>(
                                                         torch::optim::AdamOptions(3e-3).weight_decay(0.1)));
  return std::make_unique<torch::optim::Adam>(groups, torch::optim::AdamOptions(1e-2));
}

TEST(AdamStepperCuda, FusedStepsEqualLibTorchAdam) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  at::manual_seed(3);
  const auto gpu = at::TensorOptions(at::kCUDA);
  const std::vector<at::Tensor> initial{at::randn({1000, 7}, gpu), at::randn({33}, gpu), at::randn({5, 5}, gpu)};
  const std::vector<at::Tensor> reference_params = parameters_like(initial), fused_params = parameters_like(initial);
  auto reference = two_group_adam(reference_params), fused = two_group_adam(fused_params);
  train::AdamStepper stepper(*fused);
  for (int step = 0; step < 5; ++step) {
    for (size_t k = 0; k < initial.size(); ++k) {
      const bool skipped = step == 2 && k == 1;  // a parameter this step does not reach
      const at::Tensor grad = skipped ? at::Tensor() : at::randn_like(initial[k]);
      reference_params[k].mutable_grad() = grad.defined() ? grad.clone() : grad;
      fused_params[k].mutable_grad() = grad.defined() ? grad.clone() : grad;
    }
    reference->step();
    stepper.step();
    EXPECT_TRUE(stepper.fused());
    for (size_t k = 0; k < initial.size(); ++k) {
      const double difference = (reference_params[k] - fused_params[k]).abs().max().item<double>();
      EXPECT_LT(difference, 1e-5) << "parameter " << k << " after step " << step;
    }
  }
  // The optimiser's own state went along: a checkpoint of either holds the same steps and moments.
  for (size_t k = 0; k < initial.size(); ++k) {
    const torch::optim::AdamParamState* f = train::adam_state(*fused, fused_params[k]);
    const torch::optim::AdamParamState* r = train::adam_state(*reference, reference_params[k]);
    ASSERT_TRUE(f && r) << "parameter " << k;
    EXPECT_EQ(f->step(), r->step()) << "parameter " << k;
    EXPECT_LT((f->exp_avg_sq() - r->exp_avg_sq()).abs().max().item<double>(), 1e-6) << "parameter " << k;
  }
}

TEST(AdamStepperCuda, AvatarStepsEqualLibTorchAdam) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  // Two equal avatars, one stepped by LibTorch's Adam and one by the fused step, over the trainer's parameter groups.
  model::AvatarConfig config = small_config();
  model::Avatar reference(procedural_avatar_body(), subject_betas(), config);
  model::Avatar fused(procedural_avatar_body(), subject_betas(), config);
  randomise_parameters(*reference, 0.1, 41);
  copy_parameters(*reference, *fused);
  reference->to(at::kCUDA);
  fused->to(at::kCUDA);
  train::Schedule schedule;
  auto reference_adam = train::make_optimizer(reference, schedule), fused_adam = train::make_optimizer(fused, schedule);
  train::AdamStepper stepper(*fused_adam);
  const body::SmplxPose pose = test_pose(3, 0.3, true);
  for (int step = 0; step < 3; ++step) {
    for (model::Avatar* avatar : {&reference, &fused}) {
      for (at::Tensor& p : (*avatar)->parameters()) p.mutable_grad().reset();
      const model::AvatarOutput out = (*avatar)->forward(pose, kTestTime);
      (out.means.square().mean() + out.colours.mean() + out.log_scales.mean()).backward();
    }
    reference_adam->step();
    stepper.step();
    ASSERT_TRUE(stepper.fused());
    const auto fused_parameters = fused->named_parameters();
    for (const auto& p : reference->named_parameters()) {
      const at::Tensor& other = fused_parameters[p.key()];
      ASSERT_TRUE(other.isfinite().all().item<bool>()) << p.key() << " after step " << step;
      EXPECT_LT((p.value() - other).abs().max().item<double>(), 1e-5) << p.key() << " after step " << step;
    }
  }
}

}  // namespace
}  // namespace sfgs::testing
