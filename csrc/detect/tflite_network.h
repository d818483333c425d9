#pragma once
// A TensorFlow Lite graph run with LibTorch operations, on the CPU or a CUDA device: the MediaPipe models sfgs prepare
// uses (docs/prepare.md). Activations keep TensorFlow Lite's NHWC layout; convolutions see them as channels-last
// NCHW views, so no layout copies are made. Constants are converted once at load: float16 weights to float32 (what
// DEQUANTIZE gives), sparse ones densified, convolution kernels to LibTorch's layouts.
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

#include "detect/tflite_file.h"

namespace sfgs::detect {

class TfliteNetwork {
 public:
  // Refuses a graph with an operator it cannot run, naming the operator and the file. With use_graphs, a run on CUDA
  // is recorded once per input shape as a CUDA graph (common/device_graph.h) and replayed: one launch instead of a
  // few hundred operators' (a graph that cannot be recorded runs eagerly, said once on stderr); false runs every
  // operator eagerly, the reference the recordings are tested against.
  TfliteNetwork(TfliteGraph graph, at::Device device, bool use_graphs = true);
  static TfliteNetwork load(const std::string& path, at::Device device, bool use_graphs = true) {
    return {read_tflite(path), device, use_graphs};
  }

  // The graph's outputs, in its order, for inputs in its order (float32, the shapes input_shape gives, any batch);
  // the caller's own tensors, which no later run overwrites. Not for several threads at once: a network's recordings
  // share their buffers, and a run turns cuDNN and TF32 off process-wide for its duration.
  std::vector<at::Tensor> run(const std::vector<at::Tensor>& inputs) const;
  const std::vector<int64_t>& input_shape(size_t k = 0) const;
  at::Device device() const { return device_; }
  const std::string& source() const { return graph_.source; }

 private:
  struct Recording;
  std::vector<at::Tensor> run_eagerly(const std::vector<at::Tensor>& inputs) const;
  at::Tensor run_operator(const TfliteOperator& op, const std::vector<at::Tensor>& values) const;

  TfliteGraph graph_;
  at::Device device_;
  bool use_graphs_;
  // Per input shapes: the recorded run, its input and output tensors (no graph: it could not be recorded).
  mutable std::map<std::string, std::shared_ptr<Recording>> recordings_;
  std::vector<at::Tensor> constants_;           // per tensor: its value on the device (float32), or undefined
  std::vector<std::vector<int64_t>> integers_;  // per tensor: an integer constant's values, on the host
};

}  // namespace sfgs::detect
