#include "train/adam_step.h"

#include <memory>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <ATen/ATen.h>

namespace sfgs::train {
namespace {

// The optimiser's state key of a parameter: LibTorch 1.x keys by the implementation's address as text, 2.x by the
// address itself.
template <typename Map> typename Map::key_type state_key(const Map&, const at::Tensor& parameter) {
  if constexpr (std::is_same_v<typename Map::key_type, std::string>) {
    std::ostringstream text;  // as c10::guts::to_string writes it
    text << parameter.unsafeGetTensorImpl();
    return text.str();
  } else
    return static_cast<typename Map::key_type>(parameter.unsafeGetTensorImpl());
}

const torch::optim::AdamOptions& adam_options(const torch::optim::OptimizerParamGroup& group) {
  return static_cast<const torch::optim::AdamOptions&>(group.options());
}

}  // namespace

const torch::optim::AdamParamState* adam_state(torch::optim::Adam& optimizer, const at::Tensor& parameter) {
  auto& states = optimizer.state();
  const auto found = states.find(state_key(states, parameter));
  return found == states.end() ? nullptr : static_cast<const torch::optim::AdamParamState*>(found->second.get());
}

bool AdamStepper::fusable() const {
  for (const torch::optim::OptimizerParamGroup& group : optimizer_.param_groups()) {
    if (adam_options(group).amsgrad()) return false;
    for (const at::Tensor& p : group.params()) {
      if (!p.grad().defined()) continue;
      if (!p.is_cuda() || p.scalar_type() != at::kFloat || p.grad().is_sparse() || p.grad().scalar_type() != at::kFloat)
        return false;
    }
  }
  return true;
}

torch::optim::AdamParamState& AdamStepper::state_of(const at::Tensor& p, const torch::optim::AdamOptions& options) {
  auto& states = optimizer_.state();
  const auto key = state_key(states, p);
  auto found = states.find(key);
  if (found == states.end()) {
    // As LibTorch's Adam::step makes it on a parameter's first step.
    auto state = std::make_unique<torch::optim::AdamParamState>();
    state->step(0);
    state->exp_avg(at::zeros_like(p, at::MemoryFormat::Preserve));
    state->exp_avg_sq(at::zeros_like(p, at::MemoryFormat::Preserve));
    if (options.amsgrad()) state->max_exp_avg_sq(at::zeros_like(p, at::MemoryFormat::Preserve));
    found = states.emplace(key, std::move(state)).first;
  }
  return static_cast<torch::optim::AdamParamState&>(*found->second);
}

void AdamStepper::step(const at::Tensor& skip) {
  fused_ = allow_fused_ && fusable();
  if (!fused_) {
    if (!skip.defined() || skip.item<float>() == 0.0f) optimizer_.step();
    return;
  }
  at::NoGradGuard no_grad;
  for (const torch::optim::OptimizerParamGroup& group : optimizer_.param_groups()) {
    const torch::optim::AdamOptions& options = adam_options(group);
    std::vector<at::Tensor> params, grads, averages, squares, steps;
    for (const at::Tensor& p : group.params()) {
      if (!p.grad().defined()) continue;
      torch::optim::AdamParamState& state = state_of(p, options);
      DeviceStep& mirror = device_steps_[p.unsafeGetTensorImpl()];
      if (!mirror.count.defined() || mirror.host != state.step())
        mirror.count = at::full({}, double(state.step()), p.options().dtype(at::kFloat));
      state.step(state.step() + 1);  // the device copy is counted up likewise, below
      mirror.host = state.step();
      params.push_back(p);
      grads.push_back(p.grad());
      averages.push_back(state.exp_avg());
      squares.push_back(state.exp_avg_sq());
      steps.push_back(mirror.count);
    }
    if (params.empty()) continue;
    const auto [beta1, beta2] = options.betas();
    // The kernel reads the step counts as they are (the bias corrections of step t need t): count them up first, as
    // torch.optim.Adam(fused=True) does.
    at::_foreach_add_(steps, 1);
    at::_fused_adam_(params, grads, averages, squares, /*max_exp_avg_sqs=*/{}, steps, options.lr(), beta1, beta2,
                     options.weight_decay(), options.eps(), /*amsgrad=*/false, /*maximize=*/false,
                     /*grad_scale=*/c10::nullopt,
                     /*found_inf=*/skip.defined() ? c10::optional<at::Tensor>(skip) : c10::optional<at::Tensor>());
  }
}

}  // namespace sfgs::train
