#pragma once
// LPIPS v0.1 (Zhang et al. 2018; richzhang/PerceptualSimilarity, spatial=False, eval mode) with the AlexNet or
// SqueezeNet backbone, weights read from safetensors files (../shared/lpips/README.md defines the layout and
// the forward pass). Functional and differentiable: autograd reaches both images. See docs/metrics.md.
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

namespace sfgs::metrics {

enum class LpipsNet { alex, squeeze };

const char* lpips_net_name(LpipsNet net);  // "alex", "squeeze"

// <directory>/lpips_<net>.safetensors
std::string lpips_weights_file(LpipsNet net, const std::string& directory);

// Every tensor a weights file holds, with its shape (OIHW convolutions, features.* and lin*).
std::map<std::string, std::vector<int64_t>> lpips_weight_shapes(LpipsNet net);

// $SFGS_LPIPS_DIR if set, else $SFGS_SHARED_DIR/lpips, else the shared folder beside the source tree the build came
// from (SOURCE/../shared/lpips) when it exists, else ../shared/lpips relative to the working directory.
std::string default_lpips_weights_dir();

// Unit-normalised backbone activations (one (B, C_l, H_l, W_l) tensor per tap) of a batch of images, so a
// frame's features can serve several distances (see ImageEvaluator's tc-LPIPS).
struct LpipsFeatures {
  std::vector<at::Tensor> taps;
};

class Lpips {
 public:
  // Missing, unreadable or inconsistent weights throw c10::Error; the message starts with
  // "LPIPS (<net>) unavailable:" and names the file. LPIPS never silently reports 0.
  static Lpips load(LpipsNet net, const std::string& weights_file);

  // Tensors named and shaped as in the safetensors files (features.*, lin*); checked, then kept as given.
  Lpips(LpipsNet net, std::map<std::string, at::Tensor> weights);

  LpipsNet net() const { return net_; }
  at::Device device() const;
  // A copy whose weights live on `device` in `dtype`: inputs elsewhere work too, but convert the weights on
  // every call.
  Lpips to(at::Device device, at::ScalarType dtype) const;
  // A copy whose backbone (the convolutions, pools and ReLUs) runs in `trunk` (e.g. bfloat16: tensor cores, half
  // the memory traffic), channels-last on CUDA, whatever the images' dtype; the scaling layer, the taps'
  // normalisation and the distances stay in the images' dtype. bfloat16 keeps float32's range, so the small
  // gradients of the loss need no scaling. Training's loss uses it on CUDA (docs/performance.md measures the
  // effect); the metrics keep the images' dtype.
  Lpips with_trunk_dtype(at::ScalarType trunk) const;
  int64_t layer_count() const;
  // Smallest image side the backbone's strides and pools accept (alex 31, squeeze 17).
  int64_t min_image_side() const;

  // Images (H, W, 3) or (B, H, W, 3), RGB in [0, 1] (mapped to [-1, 1] inside, like torchmetrics with
  // normalize=True). Returns a 0-dim tensor or (B). The computation runs in the images' dtype (the backbone in the
  // trunk's, with_trunk_dtype) and device. When only the prediction is differentiated (the training loss), the target
  // takes its own pass without autograd, so the backward runs the backbone for the prediction alone.
  at::Tensor operator()(const at::Tensor& prediction, const at::Tensor& target) const;
  // The spatially averaged contribution of every tap (they sum to the distance): (L) or (B, L).
  at::Tensor per_layer(const at::Tensor& prediction, const at::Tensor& target) const;

  // images as for operator(); batch dimension always present in the result.
  LpipsFeatures features(const at::Tensor& images) const;
  // (B, L) per-tap distances between two feature sets of equal batch size.
  at::Tensor per_layer_distance(const LpipsFeatures& a, const LpipsFeatures& b) const;

 private:
  void check_images(const at::Tensor& images) const;
  LpipsFeatures backbone(const at::Tensor& images_nchw) const;
  at::Tensor conv_relu(const at::Tensor& x, const std::string& name, int64_t stride, int64_t padding) const;
  at::Tensor fire(const at::Tensor& x, int index) const;

  LpipsNet net_;
  std::map<std::string, at::Tensor> weights_;
  std::optional<at::ScalarType> trunk_dtype_;  // the backbone's dtype; unset: the images' (with_trunk_dtype)
  at::Tensor shift_, scale_;                   // (1, 3, 1, 1) the scaling layer's, in the weights' dtype and device
};

}  // namespace sfgs::metrics
