#include "model/mlp.h"

#include <cmath>
#include <string>
#include <utility>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "body/tensor_checks.h"
#include "model/constants.h"
#include "ops/group_norm/group_norm.h"
#include "ops/linear/linear.h"

namespace sfgs::model {
namespace {

// torch.nn.Linear's default initialisation: weight and bias uniform in +-1/sqrt(fan_in).
at::Tensor uniform_parameter(at::IntArrayRef shape, int64_t fan_in) {
  const double bound = 1.0 / std::sqrt(static_cast<double>(fan_in));
  return at::empty(shape).uniform_(-bound, bound);
}

}  // namespace

MlpImpl::MlpImpl(MlpShape shape) : shape_(std::move(shape)) {
  TORCH_CHECK(!shape_.input_widths.empty(), "Mlp: at least one input group is needed");
  int64_t fan_in = 0;
  for (int64_t w : shape_.input_widths) {
    TORCH_CHECK(w > 0, "Mlp: input widths must be positive, got ", w);
    fan_in += w;
  }
  TORCH_CHECK(shape_.output_width > 0, "Mlp: output width must be positive, got ", shape_.output_width);
  for (int64_t w : shape_.hidden_widths) {
    TORCH_CHECK(w > 0, "Mlp: hidden widths must be positive, got ", w);
    TORCH_CHECK(!shape_.group_norm || w % kMlpGroupNormGroups == 0, "Mlp: hidden width ", w,
                " must be a multiple of the ", kMlpGroupNormGroups, " GroupNorm groups");
  }
  const bool has_hidden = !shape_.hidden_widths.empty();
  const int64_t first_width = has_hidden ? shape_.hidden_widths.front() : shape_.output_width;
  const bool zero_first = !has_hidden && shape_.zero_output;

  for (size_t g = 0; g < shape_.input_widths.size(); ++g) {
    at::Tensor w = uniform_parameter({first_width, shape_.input_widths[g]}, fan_in);
    if (zero_first) w.zero_();
    input_weights_.push_back(register_parameter("input" + std::to_string(g) + "_weight", w));
  }
  at::Tensor bias = uniform_parameter({first_width}, fan_in);
  if (zero_first) bias.zero_();
  input_bias_ = register_parameter("input_bias", bias);

  for (size_t k = 0; k < shape_.hidden_widths.size(); ++k) {
    const int64_t width = shape_.hidden_widths[k];
    if (shape_.group_norm) {
      norm_weights_.push_back(register_parameter("norm" + std::to_string(k) + "_weight", at::ones({width})));
      norm_biases_.push_back(register_parameter("norm" + std::to_string(k) + "_bias", at::zeros({width})));
    }
    if (k == 0) continue;
    const int64_t previous = shape_.hidden_widths[k - 1];
    hidden_weights_.push_back(
        register_parameter("hidden" + std::to_string(k) + "_weight", uniform_parameter({width, previous}, previous)));
    hidden_biases_.push_back(
        register_parameter("hidden" + std::to_string(k) + "_bias", uniform_parameter({width}, previous)));
  }
  if (has_hidden) {
    const int64_t last = shape_.hidden_widths.back();
    at::Tensor w = uniform_parameter({shape_.output_width, last}, last);
    at::Tensor b = uniform_parameter({shape_.output_width}, last);
    if (shape_.zero_output) {
      w.zero_();
      b.zero_();
    }
    output_weight_ = register_parameter("output_weight", w);
    output_bias_ = register_parameter("output_bias", b);
  }
}

at::Tensor MlpImpl::project(size_t group, const at::Tensor& input) const {
  TORCH_CHECK(group < input_weights_.size(), "Mlp::project: group ", group, " of ", input_weights_.size());
  TORCH_CHECK(input.dim() == 2 && input.size(1) == shape_.input_widths[group], "Mlp::project: group ", group,
              " must have shape (N, ", shape_.input_widths[group], "), got ", input.sizes());
  return group == 0 && !bias_in_activation() ? linear::linear(input, input_weights_[0], input_bias_)
                                             : at::linear(input, input_weights_[group]);
}

at::Tensor MlpImpl::project_add(size_t group, const at::Tensor& input, const at::Tensor& base) const {
  TORCH_CHECK(group < input_weights_.size(), "Mlp::project_add: group ", group, " of ", input_weights_.size());
  TORCH_CHECK(input.dim() == 2 && input.size(1) == shape_.input_widths[group], "Mlp::project_add: group ", group,
              " must have shape (N, ", shape_.input_widths[group], "), got ", input.sizes());
  const int64_t width = input_weights_[group].size(0);
  TORCH_CHECK(base.defined() && base.dim() == 2 && base.size(0) == input.size(0) && base.size(1) == width &&
                  base.scalar_type() == input.scalar_type() && base.device() == input.device(),
              "Mlp::project_add: base must be a ", input.scalar_type(), " (", input.size(0), ", ", width,
              ") tensor on ", input.device(), ", got ", describe(base));
  const at::Tensor sum = at::addmm(base, input, input_weights_[group].t());
  return group == 0 && !bias_in_activation() ? sum + input_bias_ : sum;
}

bool MlpImpl::bias_in_activation() const { return shape_.group_norm && !shape_.hidden_widths.empty(); }

at::Tensor MlpImpl::activate(size_t layer, const at::Tensor& pre) const {
  if (!shape_.group_norm) return at::relu(pre);
  const at::Tensor bias = layer == 0 ? input_bias_ : at::Tensor();  // the first layer's: bias_in_activation()
  return group_norm::group_norm_relu(pre, bias, norm_weights_[layer], norm_biases_[layer], kMlpGroupNormGroups,
                                     kMlpGroupNormEpsilon);
}

at::Tensor MlpImpl::finish(const at::Tensor& first_layer) const {
  if (shape_.hidden_widths.empty()) return first_layer;
  return finish_activated(activate(0, first_layer));
}

at::Tensor MlpImpl::finish_activated(const at::Tensor& first_activation) const {
  TORCH_CHECK(!shape_.hidden_widths.empty(),
              "Mlp::finish_activated: this network has no hidden layer, so no first activation (use finish)");
  TORCH_CHECK(first_activation.defined() && first_activation.dim() == 2 &&
                  first_activation.size(1) == shape_.hidden_widths.front(),
              "Mlp::finish_activated: the first activation must have shape (N, ", shape_.hidden_widths.front(),
              "), got ", describe(first_activation));
  at::Tensor x = first_activation;
  for (size_t k = 1; k < shape_.hidden_widths.size(); ++k) {
    // With GroupNorm the fused layer adds the bias (its gradient summed in the same pass) and keeps no product.
    x = shape_.group_norm
            ? group_norm::linear_group_norm_relu(x, hidden_weights_[k - 1], hidden_biases_[k - 1], norm_weights_[k],
                                                 norm_biases_[k], kMlpGroupNormGroups, kMlpGroupNormEpsilon)
            : activate(k, linear::linear(x, hidden_weights_[k - 1], hidden_biases_[k - 1]));
  }
  return linear::linear(x, output_weight_, output_bias_);
}

bool MlpImpl::infers() const { return bias_in_activation() && !at::GradMode::is_enabled(); }

at::Tensor MlpImpl::finish_from(const at::Tensor& base, size_t group, const std::vector<at::Tensor>& parts) const {
  TORCH_CHECK(group < input_weights_.size() && !parts.empty(), "Mlp::finish_from: group ", group, " of ",
              input_weights_.size(), " with ", parts.size(), " parts");
  std::vector<int64_t> widths;
  for (const at::Tensor& part : parts) {
    TORCH_CHECK(part.defined() && part.dim() == 2, "Mlp::finish_from: parts must be (N, width) tensors, got ",
                describe(part));
    widths.push_back(part.size(1));
  }
  if (infers()) {
    const mlp_inference::Network network = inference_network(group, widths);
    if (mlp_inference::fuses(parts, network)) return mlp_inference::run(parts, base, network);
  }
  return finish(project_add(group, parts.size() == 1 ? parts[0] : at::cat(parts, 1), base));
}

at::Tensor MlpImpl::forward(const std::vector<at::Tensor>& inputs) const {
  TORCH_CHECK(inputs.size() == input_weights_.size(), "Mlp: expected ", input_weights_.size(), " input groups, got ",
              inputs.size());
  if (infers()) {
    const mlp_inference::Network network = inference_network(0, {});
    if (mlp_inference::fuses(inputs, network)) return mlp_inference::run(inputs, at::Tensor(), network);
  }
  at::Tensor first = project(0, inputs[0]);
  for (size_t g = 1; g < inputs.size(); ++g) first = first + project(g, inputs[g]);
  return finish(first);
}

gathered_mlp::GatheredMlpWeights MlpImpl::gathered_weights() const {
  TORCH_CHECK(shape_.hidden_widths.size() == 2 && !shape_.group_norm,
              "Mlp::gathered_weights: the gathered MLP has exactly two hidden layers and no GroupNorm");
  return {hidden_weights_[0], hidden_biases_[0], output_weight_, output_bias_};
}

mlp_inference::Network MlpImpl::inference_network(size_t group, const std::vector<int64_t>& widths) const {
  TORCH_CHECK(bias_in_activation(), "Mlp::inference_network: for GroupNorm networks with hidden layers");
  mlp_inference::Network n;
  if (widths.empty()) {
    n.input_weights = input_weights_;
  } else {
    int64_t column = 0;
    for (int64_t width : widths) {
      n.input_weights.push_back(input_weights_[group].narrow(1, column, width));
      column += width;
    }
    TORCH_CHECK(column == shape_.input_widths[group], "Mlp::inference_network: the blocks' widths sum to ", column,
                ", group ", group, " has ", shape_.input_widths[group], " columns");
  }
  n.first_bias = input_bias_;
  n.hidden_weights = hidden_weights_;
  n.hidden_biases = hidden_biases_;
  n.norm_weights = norm_weights_;
  n.norm_biases = norm_biases_;
  n.output_weight = output_weight_;
  n.output_bias = output_bias_;
  n.groups = kMlpGroupNormGroups;
  n.epsilon = kMlpGroupNormEpsilon;
  return n;
}

int64_t MlpImpl::parameter_count(const MlpShape& shape) {
  int64_t in = 0;
  for (int64_t w : shape.input_widths) in += w;
  int64_t count = 0;
  for (int64_t w : shape.hidden_widths) {
    count += (in + 1) * w + (shape.group_norm ? 2 * w : 0);
    in = w;
  }
  return count + (in + 1) * shape.output_width;
}

}  // namespace sfgs::model
