#pragma once
// Random GroupNorm networks for the MLP inference tests (ops/mlp_inference/mlp_inference.h): weights as
// torch.nn.Linear's initialisation draws them, GroupNorm's gamma and beta away from identity, and inputs.
#include <cmath>
#include <vector>

#include <ATen/ATen.h>

#include "model/constants.h"
#include "ops/mlp_inference/mlp_inference.h"

namespace sfgs::testing {

inline at::Tensor uniform_in(at::IntArrayRef shape, double bound, at::Generator& g) {
  return at::rand(shape, g, at::TensorOptions(at::kDouble)) * (2 * bound) - bound;
}

// In float64 on the CPU; width H, the given input blocks, `layers` hidden layers, `outputs` outputs.
inline mlp_inference::Network random_network(int64_t width, const std::vector<int64_t>& input_widths, int layers,
                                             int64_t outputs, at::Generator& g) {
  mlp_inference::Network n;
  int64_t fan_in = 0;
  for (int64_t w : input_widths) fan_in += w;
  const double first_bound = 1.0 / std::sqrt(double(fan_in)), bound = 1.0 / std::sqrt(double(width));
  for (int64_t w : input_widths) n.input_weights.push_back(uniform_in({width, w}, first_bound, g));
  n.first_bias = uniform_in({width}, first_bound, g);
  for (int k = 0; k < layers; ++k) {
    n.norm_weights.push_back(1 + 0.2 * at::randn({width}, g, at::TensorOptions(at::kDouble)));
    n.norm_biases.push_back(0.1 * at::randn({width}, g, at::TensorOptions(at::kDouble)));
    if (k == 0) continue;
    n.hidden_weights.push_back(uniform_in({width, width}, bound, g));
    n.hidden_biases.push_back(uniform_in({width}, bound, g));
  }
  n.output_weight = uniform_in({outputs, width}, bound, g);
  n.output_bias = uniform_in({outputs}, bound, g);
  n.groups = kMlpGroupNormGroups;
  n.epsilon = kMlpGroupNormEpsilon;
  return n;
}

// The network's tensors in `options`.
inline mlp_inference::Network network_to(const mlp_inference::Network& source, const at::TensorOptions& options) {
  mlp_inference::Network n = source;
  for (auto* list : {&n.input_weights, &n.hidden_weights, &n.hidden_biases, &n.norm_weights, &n.norm_biases})
    for (at::Tensor& t : *list) t = t.to(options);
  for (at::Tensor* t : {&n.first_bias, &n.output_weight, &n.output_bias}) *t = t->to(options);
  return n;
}

// One (rows, width) input per block, standard normal.
inline std::vector<at::Tensor> random_inputs(int64_t rows, const mlp_inference::Network& n, at::Generator& g) {
  std::vector<at::Tensor> inputs;
  for (const at::Tensor& w : n.input_weights)
    inputs.push_back(at::randn({rows, w.size(1)}, g, at::TensorOptions(at::kDouble)));
  return inputs;
}

}  // namespace sfgs::testing
