#include "detect/tflite_file.h"

#include <algorithm>
#include <cstring>
#include <fstream>
#include <iterator>

#include <ATen/ATen.h>
#include <c10/util/Exception.h>
#include <flatbuffers/flatbuffers.h>

namespace sfgs::detect {
namespace {

// Field indices of the schema's tables (schema.fbs; a field's vtable slot is 4 + 2 * index).
namespace field {
constexpr int kModelOperatorCodes = 1, kModelSubgraphs = 2, kModelBuffers = 4;
constexpr int kCodeDeprecatedBuiltin = 0, kCodeCustom = 1, kCodeBuiltin = 3;
constexpr int kSubgraphTensors = 0, kSubgraphInputs = 1, kSubgraphOutputs = 2, kSubgraphOperators = 3;
constexpr int kTensorShape = 0, kTensorType = 1, kTensorBuffer = 2, kTensorName = 3, kTensorSparsity = 6;
constexpr int kOperatorCode = 0, kOperatorInputs = 1, kOperatorOutputs = 2, kOperatorOptions = 4;
constexpr int kBufferData = 0;
constexpr int kSparsityTraversal = 0, kSparsityBlockMap = 1, kSparsityDimensions = 2;
constexpr int kDimensionFormat = 0, kDimensionDenseSize = 1, kDimensionSegmentsType = 2, kDimensionSegments = 3,
              kDimensionIndicesType = 4, kDimensionIndices = 5;
constexpr int kIndexVectorValues = 0;
}  // namespace field

// The SparseIndexVector union's member types.
enum IndexVectorType : uint8_t { kNoIndexVector = 0, kInt32Vector = 1, kUint16Vector = 2, kUint8Vector = 3 };

constexpr flatbuffers::voffset_t slot(int index) { return flatbuffers::voffset_t(4 + 2 * index); }

// One table of the file, every access checked against the file's bytes.
class Node {
 public:
  Node(const flatbuffers::Table* table, flatbuffers::Verifier* verifier, const std::string* source)
      : table_(table), verifier_(verifier), source_(source) {}

  template <typename T> T scalar(int index, T fallback) const {
    check(table_->VerifyField<T>(*verifier_, slot(index), sizeof(T)), "a scalar field");
    return table_->GetField<T>(slot(index), fallback);
  }
  bool has(int index) const { return table_->GetOptionalFieldOffset(slot(index)) != 0; }
  // The table at field `index`, which must be present.
  Node table(int index) const {
    check(table_->VerifyOffset(*verifier_, slot(index)), "a table offset");
    const auto* t = table_->GetPointer<const flatbuffers::Table*>(slot(index));
    check(t != nullptr, "a table that is required");
    check(t->VerifyTableStart(*verifier_), "a table");
    verifier_->EndTable();
    return Node(t, verifier_, source_);
  }
  template <typename T> std::vector<T> values(int index) const {
    const auto* v = vector<T>(index);
    return v == nullptr ? std::vector<T>() : std::vector<T>(v->begin(), v->end());
  }
  template <typename T> const flatbuffers::Vector<T>* vector(int index) const {
    check(table_->VerifyOffset(*verifier_, slot(index)), "a vector offset");
    const auto* v = table_->GetPointer<const flatbuffers::Vector<T>*>(slot(index));
    check(v == nullptr || verifier_->VerifyVector(v), "a vector");
    return v;
  }
  std::vector<Node> tables(int index) const {
    std::vector<Node> out;
    const auto* v = vector<flatbuffers::Offset<flatbuffers::Table>>(index);
    if (v == nullptr) return out;
    for (flatbuffers::uoffset_t k = 0; k < v->size(); ++k) {
      const flatbuffers::Table* t = v->Get(k);
      check(t->VerifyTableStart(*verifier_), "a table in a vector");
      verifier_->EndTable();
      out.emplace_back(t, verifier_, source_);
    }
    return out;
  }
  std::string string(int index) const {
    check(table_->VerifyOffset(*verifier_, slot(index)), "a string offset");
    const auto* s = table_->GetPointer<const flatbuffers::String*>(slot(index));
    check(s == nullptr || verifier_->VerifyString(s), "a string");
    return s == nullptr ? std::string() : s->str();
  }
  void check(bool ok, const char* what) const {
    TORCH_CHECK(ok, "'", *source_, "' is not a valid TensorFlow Lite model: ", what, " lies outside the file");
  }

 private:
  const flatbuffers::Table* table_;
  flatbuffers::Verifier* verifier_;
  const std::string* source_;
};

TfliteOptions options_of(int32_t code, const Node* o) {
  TfliteOptions options;
  if (o == nullptr) return options;
  const auto activation = [&](int index) { return TfliteActivation(o->scalar<int8_t>(index, 0)); };
  switch (TfliteOp(code)) {
    case TfliteOp::kConv2d:
      options.padding = TflitePadding(o->scalar<int8_t>(0, 0));
      options.stride_w = o->scalar<int32_t>(1, 1);
      options.stride_h = o->scalar<int32_t>(2, 1);
      options.activation = activation(3);
      options.dilation_w = o->scalar<int32_t>(4, 1);
      options.dilation_h = o->scalar<int32_t>(5, 1);
      break;
    case TfliteOp::kDepthwiseConv2d:
      options.padding = TflitePadding(o->scalar<int8_t>(0, 0));
      options.stride_w = o->scalar<int32_t>(1, 1);
      options.stride_h = o->scalar<int32_t>(2, 1);
      options.depth_multiplier = o->scalar<int32_t>(3, 1);
      options.activation = activation(4);
      options.dilation_w = o->scalar<int32_t>(5, 1);
      options.dilation_h = o->scalar<int32_t>(6, 1);
      break;
    case TfliteOp::kAdd:
    case TfliteOp::kMul:
      options.activation = activation(0);
      break;
    case TfliteOp::kConcatenation:
      options.axis = o->scalar<int32_t>(0, 0);
      options.activation = activation(1);
      break;
    case TfliteOp::kMaxPool2d:
      options.padding = TflitePadding(o->scalar<int8_t>(0, 0));
      options.stride_w = o->scalar<int32_t>(1, 1);
      options.stride_h = o->scalar<int32_t>(2, 1);
      options.filter_w = o->scalar<int32_t>(3, 1);
      options.filter_h = o->scalar<int32_t>(4, 1);
      options.activation = activation(5);
      break;
    case TfliteOp::kResizeBilinear:
      options.align_corners = o->scalar<uint8_t>(2, 0) != 0;
      options.half_pixel_centers = o->scalar<uint8_t>(3, 0) != 0;
      break;
    case TfliteOp::kDepthToSpace:
      options.block_size = o->scalar<int32_t>(0, 1);
      break;
    case TfliteOp::kFullyConnected:
      options.activation = activation(0);
      options.keep_num_dims = o->scalar<uint8_t>(2, 0) != 0;
      break;
    case TfliteOp::kMean:
      options.keep_dims = o->scalar<uint8_t>(0, 0) != 0;
      break;
    case TfliteOp::kStridedSlice:
      options.begin_mask = o->scalar<int32_t>(0, 0);
      options.end_mask = o->scalar<int32_t>(1, 0);
      options.ellipsis_mask = o->scalar<int32_t>(2, 0);
      options.new_axis_mask = o->scalar<int32_t>(3, 0);
      options.shrink_axis_mask = o->scalar<int32_t>(4, 0);
      break;
    default:
      break;
  }
  return options;
}

at::ScalarType scalar_type_of(int8_t type, const std::string& source, const std::string& tensor) {
  switch (type) {
    case 0:
      return at::kFloat;
    case 1:
      return at::kHalf;
    case 2:
      return at::kInt;
    case 3:
      return at::kByte;
    case 4:
      return at::kLong;
    case 9:
      return at::kChar;
    default:
      TORCH_CHECK(false, "'", source, "': tensor '", tensor, "' has TensorFlow Lite type ", int(type),
                  ", which sfgs does not read");
  }
}

// The values of index vector `index` (a SparseIndexVector union member) of a dimension's metadata.
std::vector<int64_t> index_vector(const Node& dimension, int type_field, int value_field) {
  const auto type = IndexVectorType(dimension.scalar<uint8_t>(type_field, kNoIndexVector));
  const Node v = dimension.table(value_field);
  std::vector<int64_t> out;
  const auto append = [&](const auto& values) { out.assign(values.begin(), values.end()); };
  switch (type) {
    case kInt32Vector:
      append(v.values<int32_t>(field::kIndexVectorValues));
      break;
    case kUint16Vector:
      append(v.values<uint16_t>(field::kIndexVectorValues));
      break;
    case kUint8Vector:
      append(v.values<uint8_t>(field::kIndexVectorValues));
      break;
    default:
      v.check(false, "a sparse index vector of a known type");
  }
  return out;
}

// A constant stored sparse (dense outer dimensions and one CSR innermost dimension, the layout of pose_detection's
// 1x1 kernels) as its dense values.
at::Tensor densified(const at::Tensor& values, const std::vector<int64_t>& shape, const Node& sparsity,
                     const std::string& source, const std::string& name) {
  const std::vector<int32_t> order = sparsity.values<int32_t>(field::kSparsityTraversal);
  const std::vector<Node> dimensions = sparsity.tables(field::kSparsityDimensions);
  const size_t rank = shape.size();
  bool readable = rank >= 1 && sparsity.values<int32_t>(field::kSparsityBlockMap).empty() &&
                  dimensions.size() == rank && order.size() == rank;
  int64_t rows = 1;
  for (size_t d = 0; readable && d < rank; ++d) {
    const int8_t format = dimensions[d].scalar<int8_t>(field::kDimensionFormat, 0);
    readable = order[d] == int32_t(d) && format == (d + 1 == rank ? 1 : 0);
    if (readable && d + 1 < rank) {
      readable = dimensions[d].scalar<int32_t>(field::kDimensionDenseSize, 0) == shape[d];
      rows *= shape[d];
    }
  }
  TORCH_CHECK(readable, "'", source, "': tensor '", name,
              "' is sparse in a layout sfgs does not read (it reads dense outer dimensions and a CSR innermost one)");
  const int64_t columns = shape.back();
  const std::vector<int64_t> segments =
      index_vector(dimensions.back(), field::kDimensionSegmentsType, field::kDimensionSegments);
  const std::vector<int64_t> indices =
      index_vector(dimensions.back(), field::kDimensionIndicesType, field::kDimensionIndices);
  TORCH_CHECK(int64_t(segments.size()) == rows + 1 && int64_t(indices.size()) == values.numel() &&
                  segments.back() == values.numel(),
              "'", source, "': sparse tensor '", name, "' has inconsistent segments and indices");
  at::Tensor dense = at::zeros({rows * columns}, values.options());
  std::vector<int64_t> flat;
  for (int64_t r = 0; r < rows; ++r)
    for (int64_t k = segments[size_t(r)]; k < segments[size_t(r) + 1]; ++k) {
      TORCH_CHECK(k >= 0 && k < int64_t(indices.size()) && indices[size_t(k)] >= 0 && indices[size_t(k)] < columns, "'",
                  source, "': sparse tensor '", name, "' has an index outside its shape");
      flat.push_back(r * columns + indices[size_t(k)]);
    }
  dense.index_put_({at::tensor(flat, at::kLong)}, values.reshape({-1}));
  return dense.view(shape);
}

// Every TfliteOp with its name in TensorFlow Lite's schema.
struct NamedOp {
  TfliteOp op;
  const char* name;
};
constexpr NamedOp kNamedOps[] = {
    {TfliteOp::kAdd, "ADD"},
    {TfliteOp::kConcatenation, "CONCATENATION"},
    {TfliteOp::kConv2d, "CONV_2D"},
    {TfliteOp::kDepthwiseConv2d, "DEPTHWISE_CONV_2D"},
    {TfliteOp::kDepthToSpace, "DEPTH_TO_SPACE"},
    {TfliteOp::kDequantize, "DEQUANTIZE"},
    {TfliteOp::kFullyConnected, "FULLY_CONNECTED"},
    {TfliteOp::kLogistic, "LOGISTIC"},
    {TfliteOp::kMaxPool2d, "MAX_POOL_2D"},
    {TfliteOp::kMul, "MUL"},
    {TfliteOp::kRelu, "RELU"},
    {TfliteOp::kReshape, "RESHAPE"},
    {TfliteOp::kResizeBilinear, "RESIZE_BILINEAR"},
    {TfliteOp::kCustom, "CUSTOM"},
    {TfliteOp::kPad, "PAD"},
    {TfliteOp::kMean, "MEAN"},
    {TfliteOp::kStridedSlice, "STRIDED_SLICE"},
    {TfliteOp::kPrelu, "PRELU"},
    {TfliteOp::kDensify, "DENSIFY"},
};

const NamedOp* named_op(int32_t code) {
  for (const NamedOp& n : kNamedOps)
    if (int32_t(n.op) == code) return &n;
  return nullptr;
}

}  // namespace

std::string tflite_op_name(int32_t code) {
  const NamedOp* n = named_op(code);
  return n != nullptr ? n->name : "builtin " + std::to_string(code);
}

bool tflite_op_runs(int32_t code) {
  const NamedOp* n = named_op(code);
  return n != nullptr && n->op != TfliteOp::kCustom;
}

TfliteGraph read_tflite(const std::string& path) {
  std::ifstream file(path, std::ios::binary);
  TORCH_CHECK(file, "cannot read TensorFlow Lite model '", path, "' (run scripts/install_deps.sh to fetch the models)");
  const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  TORCH_CHECK(bytes.size() >= 8 && std::string(bytes.begin() + 4, bytes.begin() + 8) == "TFL3", "'", path,
              "' is not a TensorFlow Lite model (no TFL3 identifier)");
  TfliteGraph graph;
  graph.source = path;
  flatbuffers::Verifier verifier(bytes.data(), bytes.size(), 64, 10000000);
  TORCH_CHECK(verifier.VerifyAlignment(0, sizeof(flatbuffers::uoffset_t)) &&
                  flatbuffers::ReadScalar<flatbuffers::uoffset_t>(bytes.data()) < bytes.size(),
              "'", path, "' is not a valid TensorFlow Lite model: its root lies outside the file");
  const auto* root = flatbuffers::GetRoot<flatbuffers::Table>(bytes.data());
  TORCH_CHECK(root->VerifyTableStart(verifier), "'", path, "' is not a valid TensorFlow Lite model");
  verifier.EndTable();
  const Node model(root, &verifier, &graph.source);

  std::vector<std::pair<int32_t, std::string>> codes;
  for (const Node& c : model.tables(field::kModelOperatorCodes)) {
    const int32_t deprecated = c.scalar<int8_t>(field::kCodeDeprecatedBuiltin, 0);
    const int32_t builtin = c.scalar<int32_t>(field::kCodeBuiltin, 0);
    // Files before builtin_code existed hold the code in the deprecated byte; newer ones hold it in both, or hold a
    // placeholder (127) in the byte for codes beyond it: the larger is the code (TensorFlow Lite's own rule).
    codes.emplace_back(std::max(deprecated, builtin), c.string(field::kCodeCustom));
  }
  const std::vector<Node> buffers = model.tables(field::kModelBuffers);
  const std::vector<Node> subgraphs = model.tables(field::kModelSubgraphs);
  TORCH_CHECK(!subgraphs.empty(), "'", path, "' holds no subgraph");
  const Node& g = subgraphs[0];
  for (const Node& t : g.tables(field::kSubgraphTensors)) {
    TfliteTensor tensor;
    tensor.name = t.string(field::kTensorName);
    for (const int32_t d : t.values<int32_t>(field::kTensorShape)) tensor.shape.push_back(d);
    tensor.type = t.scalar<int8_t>(field::kTensorType, 0);
    const uint32_t b = t.scalar<uint32_t>(field::kTensorBuffer, 0);
    TORCH_CHECK(b < buffers.size(), "'", path, "': tensor '", tensor.name, "' names buffer ", b, " of ",
                buffers.size());
    const auto* data = buffers[b].vector<uint8_t>(field::kBufferData);
    if (data != nullptr && data->size() > 0) {
      const at::ScalarType type = scalar_type_of(tensor.type, path, tensor.name);
      const int64_t size = int64_t(at::elementSize(type));
      TORCH_CHECK(int64_t(data->size()) % size == 0, "'", path, "': tensor '", tensor.name, "' has ", data->size(),
                  " bytes, not a whole number of its values");
      at::Tensor values = at::empty({int64_t(data->size()) / size}, type);
      std::memcpy(values.data_ptr(), data->data(), data->size());
      if (t.has(field::kTensorSparsity)) {
        values = densified(values, tensor.shape, t.table(field::kTensorSparsity), path, tensor.name);
      } else {
        int64_t count = 1;
        for (const int64_t d : tensor.shape) count *= d;
        TORCH_CHECK(count == values.numel(), "'", path, "': tensor '", tensor.name, "' has ", values.numel(),
                    " values for its shape of ", count);
        values = values.view(tensor.shape);
      }
      tensor.constant = values;
    }
    graph.tensors.push_back(std::move(tensor));
  }
  const auto checked_indices = [&](const std::vector<int32_t>& indices, bool optional) {
    for (const int32_t i : indices)
      TORCH_CHECK((optional && i == -1) || (i >= 0 && i < int32_t(graph.tensors.size())), "'", path,
                  "': an operator or the graph names tensor ", i, " of ", graph.tensors.size());
    return indices;
  };
  graph.inputs = checked_indices(g.values<int32_t>(field::kSubgraphInputs), false);
  graph.outputs = checked_indices(g.values<int32_t>(field::kSubgraphOutputs), false);
  for (const Node& o : g.tables(field::kSubgraphOperators)) {
    TfliteOperator op;
    const uint32_t c = o.scalar<uint32_t>(field::kOperatorCode, 0);
    TORCH_CHECK(c < codes.size(), "'", path, "': an operator names code ", c, " of ", codes.size());
    op.code = codes[c].first;
    op.custom_code = codes[c].second;
    op.inputs = checked_indices(o.values<int32_t>(field::kOperatorInputs), true);
    op.outputs = checked_indices(o.values<int32_t>(field::kOperatorOutputs), false);
    if (o.has(field::kOperatorOptions)) {
      const Node options = o.table(field::kOperatorOptions);
      op.options = options_of(op.code, &options);
    }
    graph.operators.push_back(std::move(op));
  }
  return graph;
}

}  // namespace sfgs::detect
