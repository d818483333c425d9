// Argument checks of the splatting op (validation.h).
#include "ops/splat/validation.h"
#include "ops/registration.h"

#include <limits>
#include <sstream>

#include <ATen/ATen.h>

namespace sfgs::splat {

namespace {

void check_matrix(const at::Tensor& t, const char* name, int64_t rows, int64_t cols, const at::Tensor& ref) {
  TORCH_CHECK(t.defined(), "sfgs::render: ", name, " must be given (", rows, ", ", cols, ")");
  TORCH_CHECK(t.dim() == 2 && t.size(0) == rows && (cols < 0 || t.size(1) == cols), "sfgs::render: ", name,
              " must have shape (", rows, ", ", cols < 0 ? std::string("C") : std::to_string(cols), "), got ",
              describe(t));
  TORCH_CHECK(t.scalar_type() == ref.scalar_type(), "sfgs::render: ", name, " must have the dtype of means (",
              ref.scalar_type(), "), got ", describe(t));
  TORCH_CHECK(t.device() == ref.device(), "sfgs::render: ", name, " must be on the device of means (", ref.device(),
              "), got ", describe(t));
}

void check_means(const at::Tensor& means, bool on_backend_device) {
  TORCH_CHECK(means.defined(), "sfgs::render: means must be given as an (N, 3) tensor");
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3, "sfgs::render: means must have shape (N, 3), got ",
              describe(means));
  TORCH_CHECK(is_float_or_double(means), "sfgs::render: tensors must be float32 or float64, got ", describe(means));
  if (on_backend_device) check_backend_device(means);
  TORCH_CHECK(means.size(0) <= std::numeric_limits<int32_t>::max(), "sfgs::render: at most 2^31 - 1 Gaussians, got ",
              means.size(0));
}

template <typename T> void check_opacity_values(const T* v, int64_t count) {
  int64_t invalid = 0, first = -1;
  for (int64_t i = 0; i < count; ++i)
    if (!(v[i] >= T(0) && v[i] <= T(1))) {  // NaN fails both comparisons
      first = invalid == 0 ? i : first;
      ++invalid;
    }
  TORCH_CHECK(invalid == 0, "sfgs::render: ", opacity_problem(invalid, count, first, double(v[first])));
}

}  // namespace

void check_backend_device(const at::Tensor& means) {
  TORCH_CHECK(means.is_cpu() || means.is_cuda(), "sfgs::render: tensors must be on the CPU or a CUDA device, got ",
              describe(means));
  TORCH_CHECK(!means.is_cuda() || ops::kBuiltWithCuda,
              "sfgs::render: got CUDA tensors but this build of sfgs has no CUDA backend (rebuild against a CUDA "
              "LibTorch), got ",
              describe(means));
}

SplatInputs validated_inputs(const SplatInputs& g, bool on_backend_device) {
  check_means(g.means, on_backend_device);
  const int64_t n = g.means.size(0);
  const bool by_scale = g.scales.defined() || g.rotations.defined();
  TORCH_CHECK(by_scale != g.covariances.defined(),
              "sfgs::render: give either scales and rotations, or covariances (exactly one parameterisation); got ",
              by_scale ? "both" : "neither");
  SplatInputs in;
  in.means = g.means.contiguous();
  if (by_scale) {
    check_matrix(g.scales, "scales", n, 3, g.means);
    check_matrix(g.rotations, "rotations", n, 4, g.means);
    in.scales = g.scales.contiguous();
    in.rotations = g.rotations.contiguous();
  } else {
    check_matrix(g.covariances, "covariances", n, 6, g.means);
    in.covariances = g.covariances.contiguous();
  }
  TORCH_CHECK(g.opacities.defined(), "sfgs::render: opacities must be given as an (N) tensor");
  const bool column = g.opacities.dim() == 2 && g.opacities.size(1) == 1;
  TORCH_CHECK((g.opacities.dim() == 1 || column) && g.opacities.size(0) == n,
              "sfgs::render: opacities must have shape (N) or (N, 1) with N = ", n, ", got ", describe(g.opacities));
  check_matrix(column ? g.opacities : g.opacities.unsqueeze(1), "opacities", n, 1, g.means);
  in.opacities = (column ? g.opacities.squeeze(1) : g.opacities).contiguous();
  check_matrix(g.features, "features", n, -1, g.means);
  const int64_t channels = g.features.size(1);
  TORCH_CHECK(channels >= 1, "sfgs::render: features need at least one channel, got ", describe(g.features));
  in.features = g.features.contiguous();

  const at::Tensor& background = g.background;
  TORCH_CHECK(background.defined() && background.dim() == 1 && background.size(0) == channels,
              "sfgs::render: background must have shape (C) with C = ", channels, " (the feature channels), got ",
              describe(background));
  check_matrix(background.unsqueeze(0), "background", 1, channels, g.means);
  in.background = background.contiguous();
  return in;
}

void check_camera(const Camera& camera) {
  const std::string problem = camera_problem(camera);
  TORCH_CHECK(problem.empty(), "sfgs::render: ", problem);
}

void check_background_finite(const at::Tensor& background) {
  TORCH_CHECK(background.isfinite().all().item<bool>(), "sfgs::render: background must be finite, got ",
              background.cpu());
}

std::string opacity_problem(int64_t invalid, int64_t count, int64_t first_index, double first_value) {
  std::ostringstream s;
  s << "opacities must be finite and in [0, 1]; " << invalid << " of " << count << " are not (first: index "
    << first_index << ", value " << first_value << ")";
  return s.str();
}

void check_opacities(const at::Tensor& opacities) {
  if (opacities.scalar_type() == at::kDouble)
    check_opacity_values(opacities.data_ptr<double>(), opacities.numel());
  else
    check_opacity_values(opacities.data_ptr<float>(), opacities.numel());
}

}  // namespace sfgs::splat
