#pragma once
// A TensorFlow Lite model file (.tflite, a FlatBuffer) read into plain structs: its tensors with their constant
// values, its operators in execution order with the options sfgs's networks use, and the graph's inputs and outputs.
// Only what the MediaPipe Holistic models need is read (docs/prepare.md); an operator outside that set is kept by
// code and refused by the runner (tflite_network.h) with its name. Every offset is checked against the file, so a
// damaged or foreign file is an error naming it, never a crash.
#include <cstdint>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

namespace sfgs::detect {

// TensorFlow Lite's builtin operator codes that sfgs's networks run (schema.fbs, BuiltinOperator).
enum class TfliteOp : int32_t {
  kAdd = 0,
  kConcatenation = 2,
  kConv2d = 3,
  kDepthwiseConv2d = 4,
  kDepthToSpace = 5,
  kDequantize = 6,
  kFullyConnected = 9,
  kLogistic = 14,
  kMaxPool2d = 17,
  kMul = 18,
  kRelu = 19,
  kReshape = 22,
  kResizeBilinear = 23,
  kCustom = 32,
  kPad = 34,
  kMean = 40,
  kStridedSlice = 45,
  kPrelu = 54,
  kDensify = 124,
};
// The operator's name for errors ("CONV_2D", or "builtin 97" for one sfgs does not know).
std::string tflite_op_name(int32_t code);
// Whether `code` is one of TfliteOp's builtins other than CUSTOM: the operators detect/tflite_network.h runs.
bool tflite_op_runs(int32_t code);

enum class TflitePadding : int8_t { kSame = 0, kValid = 1 };
enum class TfliteActivation : int8_t { kNone = 0, kRelu = 1, kReluN1To1 = 2, kRelu6 = 3, kTanh = 4 };

// The union of the options of the operators above (each reads its own fields; the others keep their defaults).
struct TfliteOptions {
  TflitePadding padding = TflitePadding::kSame;
  int32_t stride_w = 1, stride_h = 1, dilation_w = 1, dilation_h = 1;
  int32_t filter_w = 1, filter_h = 1;  // pooling
  int32_t depth_multiplier = 1;
  TfliteActivation activation = TfliteActivation::kNone;
  int32_t axis = 0;            // concatenation
  int32_t block_size = 1;      // depth to space
  bool align_corners = false;  // resize bilinear
  bool half_pixel_centers = false;
  bool keep_dims = false;                                                                            // mean
  bool keep_num_dims = false;                                                                        // fully connected
  int32_t begin_mask = 0, end_mask = 0, ellipsis_mask = 0, new_axis_mask = 0, shrink_axis_mask = 0;  // strided slice
};

struct TfliteTensor {
  std::string name;
  std::vector<int64_t> shape;
  int8_t type = 0;      // schema TensorType: 0 float32, 1 float16, 2 int32, 4 int64, ...
  at::Tensor constant;  // the buffer's values (float16 stays float16; sparse values are densified), or undefined
};

struct TfliteOperator {
  int32_t code = 0;                      // TfliteOp, or another builtin code
  std::string custom_code;               // for kCustom
  std::vector<int32_t> inputs, outputs;  // tensor indices; -1 for an optional input left out
  TfliteOptions options;
};

struct TfliteGraph {
  std::string source;  // the file, for errors
  std::vector<TfliteTensor> tensors;
  std::vector<TfliteOperator> operators;  // in execution order
  std::vector<int32_t> inputs, outputs;
};

// Reads the first subgraph of the model at `path`.
TfliteGraph read_tflite(const std::string& path);

}  // namespace sfgs::detect
