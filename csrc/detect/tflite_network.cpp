#include "detect/tflite_network.h"

#include <algorithm>
#include <cstdio>
#include <limits>
#include <utility>

#include <ATen/ATen.h>
#include <c10/core/DeviceGuard.h>

#include "common/device_graph.h"
#include "common/matmul_precision.h"
#include "common/tensor_description.h"

namespace sfgs::detect {
namespace {

bool is(const TfliteOperator& op, TfliteOp code) { return op.code == int32_t(code); }

at::Tensor activated(const at::Tensor& x, TfliteActivation activation) {
  switch (activation) {
    case TfliteActivation::kNone:
      return x;
    case TfliteActivation::kRelu:
      return at::relu(x);
    case TfliteActivation::kReluN1To1:
      return x.clamp(-1, 1);
    case TfliteActivation::kRelu6:
      return x.clamp(0, 6);
    case TfliteActivation::kTanh:
      return at::tanh(x);
  }
  return x;
}

// TensorFlow's SAME padding of one spatial dimension: the output is ceil(size / stride), and the padding that needs
// is split with the extra pixel after (bottom, right).
std::pair<int64_t, int64_t> same_padding(int64_t size, int64_t kernel, int64_t stride, int64_t dilation) {
  const int64_t out = (size + stride - 1) / stride;
  const int64_t total = std::max<int64_t>((out - 1) * stride + (kernel - 1) * dilation + 1 - size, 0);
  return {total / 2, total - total / 2};
}

// x as NCHW (a channels-last view of the NHWC values), padded for a SAME window of `kernel` (h, w) with `fill`.
at::Tensor windowed_input(const at::Tensor& x, const TfliteOptions& o, int64_t kernel_h, int64_t kernel_w,
                          double fill) {
  const at::Tensor nchw = x.permute({0, 3, 1, 2});
  if (o.padding == TflitePadding::kValid) return nchw;
  const auto [top, bottom] = same_padding(x.size(1), kernel_h, o.stride_h, o.dilation_h);
  const auto [left, right] = same_padding(x.size(2), kernel_w, o.stride_w, o.dilation_w);
  if (top == 0 && bottom == 0 && left == 0 && right == 0) return nchw;
  return at::constant_pad_nd(nchw, {left, right, top, bottom}, fill);
}

std::vector<int64_t> int_values(const at::Tensor& t) {
  const at::Tensor v = t.to(at::kCPU, at::kLong).reshape({-1}).contiguous();
  return std::vector<int64_t>(v.data_ptr<int64_t>(), v.data_ptr<int64_t>() + v.numel());
}

at::Tensor strided_slice(const at::Tensor& x, const std::vector<int64_t>& begin, const std::vector<int64_t>& end,
                         const std::vector<int64_t>& strides, const TfliteOptions& o) {
  TORCH_CHECK(o.ellipsis_mask == 0 && o.new_axis_mask == 0,
              "STRIDED_SLICE with an ellipsis or new-axis mask is not supported");
  at::Tensor y = x;
  std::vector<int64_t> shrink;
  for (int64_t d = 0; d < int64_t(begin.size()); ++d) {
    const int64_t size = x.size(d), step = strides[size_t(d)];
    TORCH_CHECK(step > 0, "STRIDED_SLICE with a non-positive stride is not supported");
    const auto clamp = [&](int64_t v) { return std::clamp(v < 0 ? v + size : v, int64_t(0), size); };
    const int64_t from = (o.begin_mask >> d) & 1 ? 0 : clamp(begin[size_t(d)]);
    int64_t to = (o.end_mask >> d) & 1 ? size : clamp(end[size_t(d)]);
    if ((o.shrink_axis_mask >> d) & 1) {
      to = from + 1;
      shrink.push_back(d);
    }
    y = y.slice(d, from, to, step);
  }
  for (auto it = shrink.rbegin(); it != shrink.rend(); ++it) y = y.squeeze(*it);
  return y;
}

// The device as the tensors made on it name theirs ("cuda" is the current CUDA device, "cuda:0" say), so that inputs
// made with the same device compare equal to it.
at::Device indexed(at::Device device) { return at::empty({0}, at::TensorOptions().device(device)).device(); }

// cuDNN off for a scope (restored after): for these small networks LibTorch's own convolution kernels serve as well
// once recorded (120 frames of prepare at 540 x 960: 2.3 s on an H200), and cuDNN's first use of each of their
// hundreds of convolution shapes (choosing and building its plans) took the first 15-20 s of a run.
class WithoutCudnn {
 public:
  WithoutCudnn() : previous_(at::globalContext().userEnabledCuDNN()) { at::globalContext().setUserEnabledCuDNN(false); }
  ~WithoutCudnn() { at::globalContext().setUserEnabledCuDNN(previous_); }
  WithoutCudnn(const WithoutCudnn&) = delete;
  WithoutCudnn& operator=(const WithoutCudnn&) = delete;

 private:
  bool previous_;
};

}  // namespace

struct TfliteNetwork::Recording {
  std::vector<at::Tensor> inputs, outputs;
  std::unique_ptr<DeviceGraph> graph;
};

TfliteNetwork::TfliteNetwork(TfliteGraph graph, at::Device device, bool use_graphs)
    : graph_(std::move(graph)),
      device_(indexed(device)),
      use_graphs_(use_graphs),
      constants_(graph_.tensors.size()),
      integers_(graph_.tensors.size()) {
  for (const TfliteOperator& op : graph_.operators) {
    TORCH_CHECK(tflite_op_runs(op.code), "'", graph_.source, "': operator ",
                is(op, TfliteOp::kCustom) ? "CUSTOM '" + op.custom_code + "'" : tflite_op_name(op.code),
                " is not one sfgs runs");
    TORCH_CHECK(!op.outputs.empty(), "'", graph_.source, "': an operator without outputs");
  }
  for (size_t t = 0; t < graph_.tensors.size(); ++t) {
    const at::Tensor& c = graph_.tensors[t].constant;
    if (!c.defined()) continue;
    constants_[t] = (at::isFloatingType(c.scalar_type()) ? c.to(at::kFloat) : c).to(device_);
    if (!at::isFloatingType(c.scalar_type())) integers_[t] = int_values(c);
  }
  // DEQUANTIZE and DENSIFY of constants are constants themselves.
  for (const TfliteOperator& op : graph_.operators)
    if ((is(op, TfliteOp::kDequantize) || is(op, TfliteOp::kDensify)) && constants_[size_t(op.inputs[0])].defined())
      constants_[size_t(op.outputs[0])] = constants_[size_t(op.inputs[0])];
}

const std::vector<int64_t>& TfliteNetwork::input_shape(size_t k) const {
  TORCH_CHECK(k < graph_.inputs.size(), "'", graph_.source, "' has ", graph_.inputs.size(), " inputs");
  return graph_.tensors[size_t(graph_.inputs[k])].shape;
}

std::vector<at::Tensor> TfliteNetwork::run(const std::vector<at::Tensor>& inputs) const {
  TORCH_CHECK(inputs.size() == graph_.inputs.size(), "'", graph_.source, "' takes ", graph_.inputs.size(),
              " inputs, got ", inputs.size());
  std::string key;
  for (size_t k = 0; k < inputs.size(); ++k) {
    const std::vector<int64_t>& shape = input_shape(k);
    const at::Tensor& x = inputs[k];
    TORCH_CHECK(
        x.dim() == int64_t(shape.size()) && x.scalar_type() == at::kFloat && x.device() == device_ &&
            std::equal(shape.begin() + 1, shape.end(), x.sizes().begin() + 1),
        "'", graph_.source, "': input ", k, " must be a float32 tensor of shape (N",
        [&] {
          std::string s;
          for (size_t d = 1; d < shape.size(); ++d) s += ", " + std::to_string(shape[d]);
          return s;
        }(),
        ") on ", device_, ", got ", describe(x));
    for (const int64_t size : x.sizes()) key += std::to_string(size) + " ";
    key += ";";
  }
  // Float32 throughout, as TensorFlow Lite computes (TF32 convolutions moved landmarks by up to 7 px); LibTorch's own
  // convolutions are matrix products.
  const Tf32MatmulScope matmul(false);
  const WithoutCudnn own_convolutions;
  const c10::DeviceGuard on_device(device_);  // recorded and replayed on the network's device
  if (!use_graphs_ || !device_.is_cuda() || !device_graphs_available()) return run_eagerly(inputs);
  std::shared_ptr<Recording>& r = recordings_[key];
  if (!r) {
    r = std::make_shared<Recording>();
    for (const at::Tensor& x : inputs) r->inputs.push_back(x.clone());
    try {
      r->graph = capture_device_graph([&] { r->outputs = run_eagerly(r->inputs); });
    } catch (const GraphCaptureError& e) {
      std::fprintf(stderr, "sfgs: '%s' runs eagerly on CUDA (its graph could not be recorded: %s)\n",
                   graph_.source.c_str(), e.what());
      r->outputs.clear();
    }
  }
  if (!r->graph) return run_eagerly(inputs);
  for (size_t k = 0; k < inputs.size(); ++k) r->inputs[k].copy_(inputs[k]);
  r->graph->replay();
  std::vector<at::Tensor> out;
  for (const at::Tensor& y : r->outputs) out.push_back(y.clone());
  return out;
}

std::vector<at::Tensor> TfliteNetwork::run_eagerly(const std::vector<at::Tensor>& inputs) const {
  std::vector<at::Tensor> values = constants_;
  for (size_t k = 0; k < inputs.size(); ++k) values[size_t(graph_.inputs[k])] = inputs[k];
  for (const TfliteOperator& op : graph_.operators) {
    if (values[size_t(op.outputs[0])].defined()) continue;  // a constant, made at load
    values[size_t(op.outputs[0])] = run_operator(op, values);
  }
  std::vector<at::Tensor> out;
  for (const int32_t t : graph_.outputs) out.push_back(values[size_t(t)]);
  return out;
}

at::Tensor TfliteNetwork::run_operator(const TfliteOperator& op, const std::vector<at::Tensor>& values) const {
  const auto input = [&](size_t k) -> const at::Tensor& {
    TORCH_CHECK(k < op.inputs.size() && op.inputs[k] >= 0 && values[size_t(op.inputs[k])].defined(), "'", graph_.source,
                "': ", tflite_op_name(op.code), " lacks input ", k);
    return values[size_t(op.inputs[k])];
  };
  const auto optional_input = [&](size_t k) {
    return k < op.inputs.size() && op.inputs[k] >= 0 ? values[size_t(op.inputs[k])] : at::Tensor();
  };
  // An integer constant (shapes, paddings, axes), read on the host at load: no device read while running.
  const auto integers = [&](size_t k) -> const std::vector<int64_t>& {
    TORCH_CHECK(k < op.inputs.size() && op.inputs[k] >= 0 && graph_.tensors[size_t(op.inputs[k])].constant.defined(),
                "'", graph_.source, "': ", tflite_op_name(op.code), "'s input ", k, " must be a constant");
    return integers_[size_t(op.inputs[k])];
  };
  const TfliteOptions& o = op.options;
  const at::Tensor& x = input(0);
  switch (TfliteOp(op.code)) {
    case TfliteOp::kConv2d: {
      const at::Tensor w = input(1).permute({0, 3, 1, 2});  // OHWI -> OIHW
      const at::Tensor y = at::conv2d(windowed_input(x, o, w.size(2), w.size(3), 0.0), w, optional_input(2),
                                      at::IntArrayRef{o.stride_h, o.stride_w}, at::IntArrayRef{0, 0},
                                      at::IntArrayRef{o.dilation_h, o.dilation_w});
      return activated(y.permute({0, 2, 3, 1}), o.activation);
    }
    case TfliteOp::kDepthwiseConv2d: {
      const at::Tensor w = input(1).permute({3, 0, 1, 2});  // (1, kh, kw, C M) -> (C M, 1, kh, kw)
      const at::Tensor y = at::conv2d(windowed_input(x, o, w.size(2), w.size(3), 0.0), w, optional_input(2),
                                      at::IntArrayRef{o.stride_h, o.stride_w}, at::IntArrayRef{0, 0},
                                      at::IntArrayRef{o.dilation_h, o.dilation_w}, x.size(3));
      return activated(y.permute({0, 2, 3, 1}), o.activation);
    }
    case TfliteOp::kMaxPool2d: {
      const at::Tensor y =
          at::max_pool2d(windowed_input(x, o, o.filter_h, o.filter_w, -std::numeric_limits<double>::infinity()),
                         {o.filter_h, o.filter_w}, {o.stride_h, o.stride_w});
      return activated(y.permute({0, 2, 3, 1}), o.activation);
    }
    case TfliteOp::kAdd:
      return activated(x + input(1), o.activation);
    case TfliteOp::kMul:
      return activated(x * input(1), o.activation);
    case TfliteOp::kConcatenation: {
      std::vector<at::Tensor> parts;
      for (size_t k = 0; k < op.inputs.size(); ++k) parts.push_back(input(k));
      return activated(at::cat(parts, o.axis < 0 ? o.axis + x.dim() : o.axis), o.activation);
    }
    case TfliteOp::kPad: {
      const std::vector<int64_t>& p = integers(1);  // (rank, 2): before, after per dimension
      std::vector<int64_t> pads;
      for (int64_t d = x.dim() - 1; d >= 0; --d) {
        pads.push_back(p[size_t(2 * d)]);
        pads.push_back(p[size_t(2 * d + 1)]);
      }
      return at::constant_pad_nd(x, pads, 0.0);
    }
    case TfliteOp::kReshape: {
      std::vector<int64_t> shape = graph_.tensors[size_t(op.outputs[0])].shape;
      if (!shape.empty()) shape[0] = -1;  // any batch
      return x.reshape(shape);
    }
    case TfliteOp::kResizeBilinear: {
      TORCH_CHECK(o.half_pixel_centers || o.align_corners, "'", graph_.source,
                  "': RESIZE_BILINEAR without half-pixel centres or aligned corners is not supported");
      const std::vector<int64_t>& size = integers(1);
      return at::upsample_bilinear2d(x.permute({0, 3, 1, 2}), {size[0], size[1]}, o.align_corners)
          .permute({0, 2, 3, 1});
    }
    case TfliteOp::kDepthToSpace: {
      const int64_t b = o.block_size, n = x.size(0), h = x.size(1), w = x.size(2), c = x.size(3) / (b * b);
      return x.reshape({n, h, w, b, b, c}).permute({0, 1, 3, 2, 4, 5}).reshape({n, h * b, w * b, c});
    }
    case TfliteOp::kFullyConnected: {
      const at::Tensor& w = input(1);
      at::Tensor y = at::matmul(x.reshape({-1, w.size(1)}), w.t());
      if (const at::Tensor b = optional_input(2); b.defined()) y = y + b;
      if (o.keep_num_dims) {
        std::vector<int64_t> shape(x.sizes().begin(), x.sizes().end());
        shape.back() = w.size(0);
        y = y.reshape(shape);
      }
      return activated(y, o.activation);
    }
    case TfliteOp::kLogistic:
      return at::sigmoid(x);
    case TfliteOp::kRelu:
      return at::relu(x);
    case TfliteOp::kPrelu:
      return at::where(x >= 0, x, x * input(1));
    case TfliteOp::kMean: {
      std::vector<int64_t> axes = integers(1);
      for (int64_t& a : axes) a = a < 0 ? a + x.dim() : a;
      return at::mean(x, axes, o.keep_dims);
    }
    case TfliteOp::kStridedSlice:
      return strided_slice(x, integers(1), integers(2), integers(3), o);
    case TfliteOp::kDequantize:
    case TfliteOp::kDensify:
      return x.to(at::kFloat);
    default:
      break;
  }
  TORCH_CHECK(false, "'", graph_.source, "': operator ", tflite_op_name(op.code), " is not one sfgs runs");
}

}  // namespace sfgs::detect
