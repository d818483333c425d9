// CUDA backend of the splatting op: the torch side of csrc/ops/splat/cuda/rasterize_kernels.h, and the orchestration of
// its stages. Allocates outputs and the cuda::ForwardContext as tensors on the inputs' device, scratch from torch's
// caching allocator, and queues every kernel on the current stream of that device.
#include <algorithm>
#include <cstdint>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/cuda/CUDAContext.h>
#include <ATen/cuda/CUDAEvent.h>
#include <c10/cuda/CUDAException.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/splat/cuda/rasterize_kernels.h"
#include "ops/splat/backend.h"
#include "ops/splat/validation.h"

namespace sfgs::splat::cuda {
namespace {

namespace kernels = sfgs::splat::cuda_kernels;

// Scratch memory held until the backend call returns. The caching allocator hands a freed block only to work queued
// later on the same stream, so kernels queued before the return may still use it. Requests are carved out of blocks
// of at least kScratchBlockBytes, which saves most of a pass's allocator calls.
class TorchScratch {
 public:
  explicit TorchScratch(const at::Device& device) : options_(at::TensorOptions().device(device).dtype(at::kByte)) {}
  kernels::ScratchAllocator allocator() {
    return [this](std::size_t bytes) { return allocate(bytes); };
  }

 private:
  static constexpr std::size_t kScratchBlockBytes = std::size_t(4) << 20;
  static constexpr std::size_t kScratchAlignment = 256;  // what cudaMalloc guarantees

  void* allocate(std::size_t bytes) {
    bytes = (bytes + kScratchAlignment - 1) / kScratchAlignment * kScratchAlignment;
    if (bytes > left_) {
      const std::size_t block = std::max(bytes, kScratchBlockBytes);
      held_.push_back(at::empty({int64_t(block)}, options_));
      next_ = held_.back().data_ptr<uint8_t>();
      left_ = block;
    }
    void* p = next_;
    next_ += bytes;
    left_ -= bytes;
    return p;
  }

  at::TensorOptions options_;
  std::vector<at::Tensor> held_;
  uint8_t* next_ = nullptr;
  std::size_t left_ = 0;
};

template <typename T> const T* data_or_null(const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; }
template <typename T> T* mutable_data_or_null(const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; }

void check_on_device(const at::Tensor& t, const char* name, const at::Tensor& means) {
  if (!t.defined()) return;
  TORCH_CHECK(t.device() == means.device() && t.scalar_type() == means.scalar_type() && t.is_contiguous(),
              "sfgs CUDA backend: ", name, " must be a contiguous ", means.scalar_type(), " tensor on ", means.device(),
              ", got a ", t.scalar_type(), " tensor on ", t.device(), t.is_contiguous() ? "" : " (not contiguous)");
}

void check_inputs(const SplatInputs& in) {
  TORCH_CHECK(in.means.is_cuda(), "sfgs CUDA backend: means must be on a CUDA device, got ", in.means.device());
  TORCH_CHECK(is_float_or_double(in.means), "sfgs CUDA backend: tensors must be float32 or float64, got ",
              in.means.scalar_type());
  TORCH_CHECK(in.means.is_contiguous(), "sfgs CUDA backend: means must be contiguous");
  TORCH_CHECK(in.uses_covariances() != (in.scales.defined() && in.rotations.defined()),
              "sfgs CUDA backend: exactly one of covariances or scales + rotations must be given");
  TORCH_CHECK(in.features.dim() == 2 && in.features.size(1) >= 1 && in.features.size(1) <= INT32_MAX,
              "sfgs CUDA backend: features must have shape (N, C) with 1 <= C < 2^31, got ", in.features.sizes());
  check_on_device(in.scales, "scales", in.means);
  check_on_device(in.rotations, "rotations", in.means);
  check_on_device(in.covariances, "covariances", in.means);
  check_on_device(in.opacities, "opacities", in.means);
  check_on_device(in.features, "features", in.means);
  check_on_device(in.background, "background", in.means);
}

// The forward pass's one host synchronisation: BinStats sizes the per-intersection buffers and picks the binning
// path, and carries the count of invalid opacities, which is an error.
kernels::BinStats read_bin_stats(const at::Tensor& device_stats, const at::Tensor& opacities,
                                 const at::cuda::CUDAStream& stream) {
  static_assert(sizeof(kernels::BinStats) == 3 * sizeof(int64_t), "BinStats is read as three int64 values");
  const at::Tensor host = at::empty({3}, at::TensorOptions().dtype(at::kLong).pinned_memory(true));
  C10_CUDA_CHECK(cudaMemcpyAsync(host.data_ptr<int64_t>(), device_stats.data_ptr<int64_t>(), sizeof(kernels::BinStats),
                                 cudaMemcpyDeviceToHost, stream));
  at::cuda::CUDAEvent copied;
  copied.record(stream);
  copied.synchronize();
  const int64_t* v = host.data_ptr<int64_t>();
  const kernels::BinStats stats{v[0], v[1], v[2]};
  if (stats.invalid_opacities > 0) {
    // The error path may synchronise again: it names the first offender.
    const int64_t first = (~((opacities >= 0) & (opacities <= 1))).nonzero()[0][0].item<int64_t>();
    TORCH_CHECK(false, "sfgs::render: ",
                opacity_problem(stats.invalid_opacities, opacities.numel(), first, opacities[first].item<double>()));
  }
  return stats;
}

template <typename T>
Forward forward_typed(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                      const BinningBudget* budget) {
  const c10::cuda::CUDAGuard guard(in.means.device());
  const at::cuda::CUDAStream stream = at::cuda::getCurrentCUDAStream();
  TorchScratch scratch(in.means.device());
  const SplatScene<T> scene = make_scene<T>(in, camera, settings);
  const int64_t n = scene.count, h = camera.height, w = camera.width, channels = scene.channels;
  const int64_t tiles = tile_count(make_grid(int(camera.width), int(camera.height)));
  const auto real = in.means.options();
  const auto i32 = real.dtype(at::kInt);
  const auto i64 = real.dtype(at::kLong);

  // Everything but the per-intersection buffers is allocated before the size read, while the device projects.
  Forward out;
  ForwardContext& c = out.context;
  static_assert(sizeof(kernels::TileRect) == 4 * sizeof(int16_t), "TileRect is saved as an (N, 4) int16 tensor");
  c.projected = at::empty({n, kProjectedWidth}, real);
  c.tile_rects = at::empty({n, 4}, real.dtype(at::kShort));
  c.tile_offsets = at::empty({tiles + 1}, i64);
  c.tile_order = at::empty({tiles}, i32);
  const at::Tensor bin_stats = at::empty({3}, i64);
  out.outputs.radii = at::empty({n, 2}, i32);
  kernels::ForwardBuffers<T> buffers{};
  buffers.projected = c.projected.data_ptr<T>();
  buffers.tile_rects = reinterpret_cast<kernels::TileRect*>(c.tile_rects.data_ptr<int16_t>());
  buffers.radii = out.outputs.radii.data_ptr<int32_t>();
  buffers.tile_offsets = c.tile_offsets.data_ptr<int64_t>();
  buffers.tile_order = c.tile_order.data_ptr<int32_t>();
  buffers.bin_stats = reinterpret_cast<kernels::BinStats*>(bin_stats.data_ptr<int64_t>());
  kernels::project_gaussians(scene, buffers, scratch.allocator(), stream);
  out.outputs.image = at::empty({h, w, channels}, real);
  out.outputs.alpha = at::empty({h, w}, real);
  out.outputs.depth = at::empty({h, w}, real);
  c.depth_sum = at::empty({h, w}, real);
  c.final_transmittance = at::empty({h, w}, real);
  c.contributors = at::empty({h, w}, i32);
  buffers.image = out.outputs.image.data_ptr<T>();
  buffers.alpha = out.outputs.alpha.data_ptr<T>();
  buffers.depth_sum = c.depth_sum.data_ptr<T>();
  buffers.depth = out.outputs.depth.data_ptr<T>();
  buffers.final_transmittance = c.final_transmittance.data_ptr<T>();
  buffers.contributors = c.contributors.data_ptr<int32_t>();

  kernels::BinStats stats{0, 0, 0};
  if (n > 0 && budget != nullptr) {
    TORCH_CHECK(budget->counts.device() == in.means.device(), "sfgs::render: the binning budget's counts are on ",
                budget->counts.device(), ", the Gaussians on ", in.means.device());
    const kernels::BinBudget device_budget{budget->intersections, budget->longest_tile,
                                           reinterpret_cast<kernels::BinStats*>(budget->counts.data_ptr<int64_t>())};
    stats = kernels::apply_bin_budget(scene, buffers, device_budget, stream);
  } else if (n > 0) {
    stats = read_bin_stats(bin_stats, in.opacities, stream);
  } else if (budget != nullptr) {
    budget->counts.zero_();
  }
  c.isect_gaussian = at::empty({stats.intersections}, i32);
  buffers.isect_gaussian = c.isect_gaussian.data_ptr<int32_t>();
  kernels::bin_intersections(scene, buffers, stats, scratch.allocator(), stream);
  kernels::blend(scene, buffers, stats, budget == nullptr, scratch.allocator(), stream);
  return out;
}

template <typename T>
InputGradients backward_typed(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                              const at::Tensor& image, const ForwardContext& c, const OutputGradients& grads) {
  const c10::cuda::CUDAGuard guard(in.means.device());
  const at::cuda::CUDAStream stream = at::cuda::getCurrentCUDAStream();
  TorchScratch scratch(in.means.device());
  const SplatScene<T> scene = make_scene<T>(in, camera, settings);
  const at::Tensor grad_image = grads.image.defined() ? grads.image.contiguous() : at::Tensor();
  const at::Tensor grad_alpha = grads.alpha.defined() ? grads.alpha.contiguous() : at::Tensor();
  const at::Tensor grad_depth = grads.depth_sum.defined() ? grads.depth_sum.contiguous() : at::Tensor();
  check_on_device(grad_image, "the image gradient", in.means);
  check_on_device(grad_alpha, "the alpha gradient", in.means);
  check_on_device(grad_depth, "the depth gradient", in.means);
  check_on_device(image, "the saved image", in.means);

  const kernels::BackwardInputs<T> inputs{c.projected.data_ptr<T>(),
                                          reinterpret_cast<const kernels::TileRect*>(c.tile_rects.data_ptr<int16_t>()),
                                          c.isect_gaussian.data_ptr<int32_t>(),
                                          c.tile_offsets.data_ptr<int64_t>(),
                                          c.tile_order.data_ptr<int32_t>(),
                                          c.isect_gaussian.numel(),
                                          image.data_ptr<T>(),
                                          c.depth_sum.data_ptr<T>(),
                                          c.final_transmittance.data_ptr<T>(),
                                          c.contributors.data_ptr<int32_t>(),
                                          data_or_null<T>(grad_image),
                                          data_or_null<T>(grad_alpha),
                                          data_or_null<T>(grad_depth)};

  InputGradients out;
  out.means = at::empty_like(in.means);
  out.opacities = at::empty_like(in.opacities);
  out.features = at::empty_like(in.features);
  out.background = at::empty_like(in.background);
  if (in.uses_covariances()) {
    out.covariances = at::empty_like(in.covariances);
  } else {
    out.scales = at::empty_like(in.scales);
    out.rotations = at::empty_like(in.rotations);
  }
  const Gradients<T> gradients{out.means.data_ptr<T>(),
                               mutable_data_or_null<T>(out.scales),
                               mutable_data_or_null<T>(out.rotations),
                               mutable_data_or_null<T>(out.covariances),
                               out.opacities.data_ptr<T>(),
                               out.features.data_ptr<T>(),
                               out.background.data_ptr<T>()};
  kernels::backward(scene, inputs, gradients, settings.deterministic, scratch.allocator(), stream);
  return out;
}

}  // namespace

Forward forward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                const BinningBudget* budget) {
  check_inputs(in);
  if (in.means.scalar_type() == at::kDouble) return forward_typed<double>(in, camera, settings, budget);
  return forward_typed<float>(in, camera, settings, budget);
}

InputGradients backward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                        const at::Tensor& image, const ForwardContext& context, const OutputGradients& grads) {
  check_inputs(in);
  if (in.means.scalar_type() == at::kDouble) return backward_typed<double>(in, camera, settings, image, context, grads);
  return backward_typed<float>(in, camera, settings, image, context, grads);
}

}  // namespace sfgs::splat::cuda
