// LPIPS as plain ATen calls on a name -> tensor map. The weights are frozen and never trained, so an
// nn::Module would add parameter registration, train/eval state and heavy headers for nothing; autograd still
// differentiates the images through at::conv2d / max_pool2d / relu.
#include "metrics/lpips.h"

#include <array>
#include <cstdlib>
#include <filesystem>
#include <utility>

#include <ATen/ATen.h>

#include "metrics/constants.h"
#include "metrics/image_layout.h"
#include "metrics/safetensors.h"

namespace sfgs::metrics {
namespace {

// (1, 3, 1, 1) per-channel constants of the scaling layer.
at::Tensor scaling_constant(const double (&values)[3], const at::TensorOptions& options) {
  return at::tensor(std::vector<double>(values, values + 3), at::kDouble).to(options).view({1, 3, 1, 1});
}

struct ConvShape {
  std::string name;  // without ".weight" / ".bias"
  int64_t out, in, kernel;
};

struct FireShape {
  int index;
  int64_t in, squeeze, expand;
};

// torchvision squeezenet1_1().features' Fire modules (index, in, squeeze, expand).
const std::vector<FireShape>& squeeze_fires() {
  static const std::vector<FireShape> fires = {{3, 64, 16, 64},    {4, 128, 16, 64},  {6, 128, 32, 128},
                                               {7, 256, 32, 128},  {9, 256, 48, 192}, {10, 384, 48, 192},
                                               {11, 384, 64, 256}, {12, 512, 64, 256}};
  return fires;
}

std::vector<ConvShape> backbone_convs(LpipsNet net) {
  if (net == LpipsNet::alex) {
    return {{"features.0", 64, 3, 11},
            {"features.3", 192, 64, 5},
            {"features.6", 384, 192, 3},
            {"features.8", 256, 384, 3},
            {"features.10", 256, 256, 3}};
  }
  std::vector<ConvShape> convs = {{"features.0", 64, 3, 3}};
  for (const FireShape& f : squeeze_fires()) {
    const std::string prefix = "features." + std::to_string(f.index);
    convs.push_back({prefix + ".squeeze", f.squeeze, f.in, 1});
    convs.push_back({prefix + ".expand1x1", f.expand, f.squeeze, 1});
    convs.push_back({prefix + ".expand3x3", f.expand, f.squeeze, 3});
  }
  return convs;
}

std::vector<int64_t> tap_channels(LpipsNet net) {
  if (net == LpipsNet::alex) return {64, 192, 384, 256, 256};
  return {64, 128, 256, 384, 384, 512, 512};
}

at::Tensor max_pool(const at::Tensor& x, bool ceil_mode) {
  return at::max_pool2d(x, {3, 3}, {2, 2}, {0, 0}, {1, 1}, ceil_mode);
}

}  // namespace

const char* lpips_net_name(LpipsNet net) { return net == LpipsNet::alex ? "alex" : "squeeze"; }

std::string lpips_weights_file(LpipsNet net, const std::string& directory) {
  return directory + "/lpips_" + lpips_net_name(net) + ".safetensors";
}

std::string default_lpips_weights_dir() {
  if (const char* dir = std::getenv("SFGS_LPIPS_DIR"); dir && *dir) return dir;
  if (const char* shared = std::getenv("SFGS_SHARED_DIR"); shared && *shared) return std::string(shared) + "/lpips";
  // The shared folder beside the source tree this build came from, wherever the command runs; then beside the
  // working directory (a build moved away from its sources).
  const std::string beside_sources = std::string(SFGS_SOURCE_DIR) + "/../shared/lpips";
  if (std::filesystem::is_directory(beside_sources)) return beside_sources;
  return "../shared/lpips";
}

std::map<std::string, std::vector<int64_t>> lpips_weight_shapes(LpipsNet net) {
  std::map<std::string, std::vector<int64_t>> shapes;
  for (const ConvShape& c : backbone_convs(net)) {
    shapes[c.name + ".weight"] = {c.out, c.in, c.kernel, c.kernel};
    shapes[c.name + ".bias"] = {c.out};
  }
  const std::vector<int64_t> channels = tap_channels(net);
  for (size_t l = 0; l < channels.size(); ++l) shapes["lin" + std::to_string(l) + ".weight"] = {1, channels[l], 1, 1};
  return shapes;
}

Lpips Lpips::load(LpipsNet net, const std::string& weights_file) {
  const std::string unavailable = std::string("LPIPS (") + lpips_net_name(net) + ") unavailable: ";
  SafetensorsContent content;
  try {
    content = read_safetensors(weights_file);
  } catch (const c10::Error& e) {
    TORCH_CHECK(false, unavailable, e.what_without_backtrace());  // the reader's message names the file
  }
  try {
    return Lpips(net, std::move(content.tensors));
  } catch (const c10::Error& e) {
    TORCH_CHECK(false, unavailable, "weights file '", weights_file, "': ", e.what_without_backtrace());
  }
}

Lpips::Lpips(LpipsNet net, std::map<std::string, at::Tensor> weights) : net_(net), weights_(std::move(weights)) {
  const auto expected = lpips_weight_shapes(net);
  for (const auto& [name, shape] : expected) {
    const auto it = weights_.find(name);
    TORCH_CHECK(it != weights_.end(), "LPIPS (", lpips_net_name(net), ") weights: missing tensor '", name, "'");
    TORCH_CHECK(it->second.sizes() == at::IntArrayRef(shape) && at::isFloatingType(it->second.scalar_type()), "LPIPS (",
                lpips_net_name(net), ") weights: tensor '", name, "' must be a floating tensor of shape ",
                at::IntArrayRef(shape), ", got ", describe(it->second));
  }
  for (const auto& [name, tensor] : weights_) {
    TORCH_CHECK(expected.count(name), "LPIPS (", lpips_net_name(net), ") weights: unexpected tensor '", name,
                "' (is this the ", lpips_net_name(net), " file?)");
  }
  // The scaling layer's constants, kept beside the weights: made per call they would be a host upload each time,
  // which a CUDA graph cannot record.
  shift_ = scaling_constant(kLpipsShift, weights_.begin()->second.options());
  scale_ = scaling_constant(kLpipsScale, weights_.begin()->second.options());
}

at::Device Lpips::device() const { return weights_.begin()->second.device(); }

Lpips Lpips::to(at::Device device, at::ScalarType dtype) const {
  std::map<std::string, at::Tensor> converted;
  for (const auto& [name, tensor] : weights_) converted.emplace(name, tensor.to(device, dtype));
  return Lpips(net_, std::move(converted));
}

Lpips Lpips::with_trunk_dtype(at::ScalarType trunk) const {
  TORCH_CHECK(at::isFloatingType(trunk), "Lpips::with_trunk_dtype: the trunk needs a floating dtype, got ", trunk);
  Lpips copy = *this;
  for (auto& [name, tensor] : copy.weights_) {
    if (name.rfind("features.", 0) != 0) continue;  // the lin* weights weigh the distances, in the images' dtype
    tensor = tensor.to(trunk);
    if (tensor.dim() == 4 && tensor.is_cuda()) tensor = tensor.contiguous(at::MemoryFormat::ChannelsLast);
  }
  copy.trunk_dtype_ = trunk;
  return copy;
}

int64_t Lpips::layer_count() const { return int64_t(tap_channels(net_).size()); }

int64_t Lpips::min_image_side() const {
  // alex: conv 11/4 and two 3/2 pools must leave 1 pixel; squeeze: conv 3/2 and three 3/2 ceil-mode pools.
  return net_ == LpipsNet::alex ? 31 : 17;
}

at::Tensor Lpips::conv_relu(const at::Tensor& x, const std::string& name, int64_t stride, int64_t padding) const {
  const at::Tensor& weight = weights_.at(name + ".weight");
  const at::Tensor& bias = weights_.at(name + ".bias");
  const std::array<int64_t, 2> strides = {stride, stride}, paddings = {padding, padding}, dilations = {1, 1};
  // Every convolution of both backbones feeds a ReLU; in place saves a feature map's memory.
  return at::conv2d(x, weight.to(x.options()), bias.to(x.options()), strides, paddings, dilations, 1).relu_();
}

at::Tensor Lpips::fire(const at::Tensor& x, int index) const {
  const std::string prefix = "features." + std::to_string(index);
  const at::Tensor squeezed = conv_relu(x, prefix + ".squeeze", 1, 0);
  return at::cat({conv_relu(squeezed, prefix + ".expand1x1", 1, 0), conv_relu(squeezed, prefix + ".expand3x3", 1, 1)},
                 1);
}

LpipsFeatures Lpips::backbone(const at::Tensor& images_nchw) const {
  // ScalingLayer applied to 2v - 1: the images arrive in [0, 1].
  const auto options = images_nchw.options();
  const bool kept = shift_.dtype() == options.dtype() && shift_.device() == options.device();
  const at::Tensor shift = kept ? shift_ : scaling_constant(kLpipsShift, options);
  const at::Tensor scale = kept ? scale_ : scaling_constant(kLpipsScale, options);
  at::Tensor x = (images_nchw * 2.0 - 1.0 - shift) / scale;
  if (trunk_dtype_ && *trunk_dtype_ != x.scalar_type()) {
    x = x.to(*trunk_dtype_);
    // cuDNN's tensor-core kernels take NHWC; in NCHW every convolution would be wrapped in two transposes.
    if (x.is_cuda()) x = x.contiguous(at::MemoryFormat::ChannelsLast);
  }

  LpipsFeatures f;
  if (net_ == LpipsNet::alex) {
    // Taps after the ReLUs at features indices 1, 4, 7, 9, 11; the pools round down.
    x = conv_relu(x, "features.0", 4, 2);
    f.taps.push_back(x);
    x = conv_relu(max_pool(x, false), "features.3", 1, 2);
    f.taps.push_back(x);
    x = conv_relu(max_pool(x, false), "features.6", 1, 1);
    f.taps.push_back(x);
    x = conv_relu(x, "features.8", 1, 1);
    f.taps.push_back(x);
    x = conv_relu(x, "features.10", 1, 1);
    f.taps.push_back(x);
  } else {
    // Taps at features indices 1, 4, 7, 9, 10, 11, 12; the pools round up (ceil_mode), which matters for
    // odd feature sizes.
    x = conv_relu(x, "features.0", 2, 0);
    f.taps.push_back(x);
    x = fire(fire(max_pool(x, true), 3), 4);
    f.taps.push_back(x);
    x = fire(fire(max_pool(x, true), 6), 7);
    f.taps.push_back(x);
    x = fire(max_pool(x, true), 9);
    f.taps.push_back(x);
    for (int index : {10, 11, 12}) {
      x = fire(x, index);
      f.taps.push_back(x);
    }
  }
  for (at::Tensor& tap : f.taps) {
    tap = tap.to(options.dtype());  // the normalisation's sum of squares over the channels in the images' dtype
    const at::Tensor norm = at::sqrt(tap.pow(2).sum(1, true).clamp_min(kLpipsMinSquaredNorm));
    tap = tap / (norm + kLpipsNormEpsilon);
  }
  return f;
}

void Lpips::check_images(const at::Tensor& images) const {
  TORCH_CHECK(images.defined() && (images.dim() == 3 || images.dim() == 4) && images.size(-1) == 3 &&
                  at::isFloatingType(images.scalar_type()),
              "lpips: images must be floating RGB (H, W, 3) or (B, H, W, 3) in [0, 1], got ", describe(images));
  TORCH_CHECK(images.size(-3) >= min_image_side() && images.size(-2) >= min_image_side(), "lpips (",
              lpips_net_name(net_), "): images must be at least ", min_image_side(), " x ", min_image_side(),
              " pixels, got ", describe(images));
}

LpipsFeatures Lpips::features(const at::Tensor& images) const {
  check_images(images);
  return backbone(detail::to_batch_nchw(images));
}

at::Tensor Lpips::per_layer_distance(const LpipsFeatures& a, const LpipsFeatures& b) const {
  TORCH_CHECK(int64_t(a.taps.size()) == layer_count() && int64_t(b.taps.size()) == layer_count(),
              "lpips: feature sets must have ", layer_count(), " taps, got ", a.taps.size(), " and ", b.taps.size());
  std::vector<at::Tensor> layers;
  for (int64_t l = 0; l < layer_count(); ++l) {
    TORCH_CHECK(a.taps[l].sizes() == b.taps[l].sizes(), "lpips: tap ", l,
                " differs in shape between the images: ", describe(a.taps[l]), " and ", describe(b.taps[l]));
    // The 1x1 lin conv commutes with the spatial mean: average the squared differences first, then weigh.
    const at::Tensor mean_square = (a.taps[l] - b.taps[l]).pow(2).mean({2, 3});
    const at::Tensor lin = weights_.at("lin" + std::to_string(l) + ".weight").to(mean_square.options()).flatten();
    layers.push_back(at::matmul(mean_square, lin));
  }
  return at::stack(layers, 1);
}

at::Tensor Lpips::per_layer(const at::Tensor& prediction, const at::Tensor& target) const {
  detail::check_image_pair("lpips", prediction, target, 3);
  check_images(prediction);
  if (at::GradMode::is_enabled() && prediction.requires_grad() && !target.requires_grad()) {
    // A batch of both would make autograd run the backbone's backward for the target too.
    LpipsFeatures target_features;
    {
      at::NoGradGuard no_grad;
      target_features = features(target);
    }
    return detail::match_batch_layout(per_layer_distance(features(prediction), target_features), prediction);
  }
  // One backbone pass over both images.
  const LpipsFeatures both = features(at::cat({prediction.dim() == 3 ? prediction.unsqueeze(0) : prediction,
                                               target.dim() == 3 ? target.unsqueeze(0) : target}));
  const int64_t batch = both.taps.front().size(0) / 2;
  LpipsFeatures a, b;
  for (const at::Tensor& tap : both.taps) {
    a.taps.push_back(tap.narrow(0, 0, batch));
    b.taps.push_back(tap.narrow(0, batch, batch));
  }
  return detail::match_batch_layout(per_layer_distance(a, b), prediction);
}

at::Tensor Lpips::operator()(const at::Tensor& prediction, const at::Tensor& target) const {
  return per_layer(prediction, target).sum(-1);
}

}  // namespace sfgs::metrics
