#pragma once
// A TensorFlow Lite graph run with LibTorch operations, on the CPU or a CUDA device: the MediaPipe models sfgs prepare
// uses (docs/prepare.md). Activations keep TensorFlow Lite's NHWC layout; convolutions see them as channels-last
// NCHW views, so no layout copies are made. Constants are converted once at load: float16 weights to float32 (what
// DEQUANTIZE gives), sparse ones densified, convolution kernels to LibTorch's layouts.
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

#include "detect/tflite_file.h"

namespace sfgs::detect {

class TfliteNetwork {
 public:
  // Refuses a graph with an operator it cannot run, naming the operator and the file.
  TfliteNetwork(TfliteGraph graph, at::Device device);
  static TfliteNetwork load(const std::string& path, at::Device device) { return {read_tflite(path), device}; }

  // The graph's outputs, in its order, for inputs in its order (float32, the shapes input_shape gives, any batch).
  std::vector<at::Tensor> run(const std::vector<at::Tensor>& inputs) const;
  const std::vector<int64_t>& input_shape(size_t k = 0) const;
  at::Device device() const { return device_; }
  const std::string& source() const { return graph_.source; }

 private:
  at::Tensor run_operator(const TfliteOperator& op, const std::vector<at::Tensor>& values) const;

  TfliteGraph graph_;
  at::Device device_;
  std::vector<at::Tensor> constants_;           // per tensor: its value on the device (float32), or undefined
  std::vector<std::vector<int64_t>> integers_;  // per tensor: an integer constant's values, on the host
};

}  // namespace sfgs::detect
