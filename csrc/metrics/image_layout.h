#pragma once
// Validation and layout helpers shared by the image metrics (internal to csrc/metrics).
#include <string>

#include <ATen/core/Tensor.h>

#include "common/tensor_description.h"

namespace sfgs::metrics::detail {

// Checks that two images are defined, floating, on one device with one dtype, of equal shape (H, W, C) or
// (B, H, W, C), non-empty, and (when channels > 0) have that many channels. `metric` prefixes the messages.
void check_image_pair(const char* metric, const at::Tensor& prediction, const at::Tensor& target, int64_t channels = 0);

// (H, W, C) or (B, H, W, C) channels-last image to a contiguous (B, C, H, W) batch.
at::Tensor to_batch_nchw(const at::Tensor& image);

// A per-image result of shape (B) back to the caller's layout: 0-dim when `image` had no batch dimension.
at::Tensor match_batch_layout(const at::Tensor& per_image, const at::Tensor& image);

}  // namespace sfgs::metrics::detail
