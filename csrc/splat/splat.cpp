// The splatting op's public boundary: input validation with messages that say what was expected and what came,
// the autograd node, and dispatch to the CPU or CUDA backend by device.
#include "splat/splat.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>

#include <ATen/TensorOperators.h>
#include <torch/csrc/autograd/custom_function.h>

#include "splat/backend.h"

namespace sfgs {
namespace {

using splat::BackendSettings;
using splat::CameraSpec;
using splat::SplatInputs;
using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

std::string describe(const at::Tensor& t) {
  if (!t.defined()) return "an undefined tensor";
  std::ostringstream s;
  s << "a " << t.scalar_type() << " tensor of shape " << t.sizes() << " on " << t.device();
  return s.str();
}

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

SplatInputs validated_inputs(const Gaussians& g, const at::Tensor& background, const RenderOptions& options) {
  TORCH_CHECK(g.means.defined(), "sfgs::render: means must be given as an (N, 3) tensor");
  TORCH_CHECK(g.means.dim() == 2 && g.means.size(1) == 3, "sfgs::render: means must have shape (N, 3), got ",
              describe(g.means));
  TORCH_CHECK(g.means.scalar_type() == at::kFloat || g.means.scalar_type() == at::kDouble,
              "sfgs::render: tensors must be float32 or float64, got ", describe(g.means));
  TORCH_CHECK(g.means.is_cpu() || g.means.is_cuda(), "sfgs::render: tensors must be on the CPU or a CUDA device, got ",
              describe(g.means));
  TORCH_CHECK(!g.means.is_cuda() || splat::cuda::available(),
              "sfgs::render: got CUDA tensors but this build of sfgs has no CUDA backend (rebuild against a CUDA "
              "LibTorch), got ",
              describe(g.means));
  const int64_t n = g.means.size(0);
  TORCH_CHECK(n <= std::numeric_limits<int32_t>::max(), "sfgs::render: at most 2^31 - 1 Gaussians, got ", n);

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

  TORCH_CHECK(background.defined() && background.dim() == 1 && background.size(0) == channels,
              "sfgs::render: background must have shape (C) with C = ", channels, " (the feature channels), got ",
              describe(background));
  check_matrix(background.unsqueeze(0), "background", 1, channels, g.means);
  if (background.is_cpu() || options.check_background)
    TORCH_CHECK(background.isfinite().all().item<bool>(), "sfgs::render: background must be finite, got ",
                background.cpu());
  in.background = background.contiguous();
  return in;
}

CameraSpec validated_camera(const Camera& c) {
  const std::string problem = camera_problem(c);
  TORCH_CHECK(problem.empty(), "sfgs::render: ", problem);
  return CameraSpec{c.world_to_camera, c.fx, c.fy, c.cx, c.cy, int(c.width), int(c.height), c.near_plane,
                    c.far_plane};
}

// Autograd context keys for the non-tensor arguments.
constexpr const char* kCameraKey = "camera";
constexpr const char* kSettingsKey = "settings";
constexpr const char* kUsesCovariancesKey = "uses_covariances";
constexpr int kNumInputs = 7;  // means, scales, rotations, covariances, opacities, features, background
constexpr int kNumSavedBeforeState = kNumInputs + 2;  // the inputs, then the alpha and depth outputs

std::vector<double> pack_camera(const CameraSpec& c) {
  std::vector<double> v(c.world_to_camera.begin(), c.world_to_camera.end());
  v.insert(v.end(), {c.fx, c.fy, c.cx, c.cy, double(c.width), double(c.height), c.near_plane, c.far_plane});
  return v;
}

CameraSpec unpack_camera(const std::vector<double>& v) {
  CameraSpec c;
  std::copy(v.begin(), v.begin() + 16, c.world_to_camera.begin());
  c.fx = v[16]; c.fy = v[17]; c.cx = v[18]; c.cy = v[19];
  c.width = int(v[20]); c.height = int(v[21]);
  c.near_plane = v[22]; c.far_plane = v[23];
  return c;
}

std::vector<double> pack_settings(const BackendSettings& s) {
  return {s.projection.low_pass_variance, double(s.projection.antialiased), double(s.deterministic)};
}

BackendSettings unpack_settings(const std::vector<double>& v) {
  return BackendSettings{splat::ProjectionSettings{v[0], v[1] != 0}, v[2] != 0};
}

class SplatFunction : public torch::autograd::Function<SplatFunction> {
 public:
  // The unused parameterisation arrives as nullopt: autograd then treats it as a non-tensor argument.
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const c10::optional<at::Tensor>& scales,
                               const c10::optional<at::Tensor>& rotations,
                               const c10::optional<at::Tensor>& covariances, const at::Tensor& opacities,
                               const at::Tensor& features, const at::Tensor& background, const CameraSpec& camera,
                               const BackendSettings& settings) {
    const SplatInputs in{means, scales.value_or(at::Tensor()), rotations.value_or(at::Tensor()),
                         covariances.value_or(at::Tensor()), opacities, features, background};
    splat::ForwardOutputs out = means.is_cuda() ? splat::cuda::forward(in, camera, settings)
                                                : splat::cpu::forward(in, camera, settings);
    variable_list to_save = {means, in.scales, in.rotations, in.covariances, opacities, features, background,
                             out.alpha, out.depth};
    to_save.insert(to_save.end(), out.saved.begin(), out.saved.end());
    ctx->save_for_backward(to_save);
    ctx->saved_data[kCameraKey] = pack_camera(camera);
    ctx->saved_data[kSettingsKey] = pack_settings(settings);
    ctx->saved_data[kUsesCovariancesKey] = in.uses_covariances();
    ctx->mark_non_differentiable({out.radii});
    // Outputs nobody differentiates (often depth and alpha) arrive as undefined gradients, not zero-filled tensors.
    ctx->set_materialize_grads(false);
    return {out.image, out.alpha, out.depth, out.radii};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grad_outputs) {
    const variable_list saved = ctx->get_saved_variables();
    SplatInputs in{saved[0], saved[1], saved[2], saved[3], saved[4], saved[5], saved[6]};
    if (ctx->saved_data[kUsesCovariancesKey].toBool()) {
      in.scales = at::Tensor();
      in.rotations = at::Tensor();
    } else {
      in.covariances = at::Tensor();
    }
    splat::ForwardOutputs fwd;
    fwd.saved.assign(saved.begin() + kNumSavedBeforeState, saved.end());
    const CameraSpec camera = unpack_camera(ctx->saved_data[kCameraKey].toDoubleVector());
    const BackendSettings settings = unpack_settings(ctx->saved_data[kSettingsKey].toDoubleVector());
    splat::OutputGradients grads{grad_outputs[0], grad_outputs[1], at::Tensor()};
    if (grad_outputs[2].defined()) {
      // depth = depth_sum / alpha where alpha > 0: d/d depth_sum = 1 / alpha, d/d alpha = -depth / alpha.
      const at::Tensor& alpha = saved[kNumInputs];
      const at::Tensor& depth = saved[kNumInputs + 1];
      const at::Tensor covered = alpha > 0;
      const at::Tensor per_alpha = at::where(covered, grad_outputs[2] / alpha.clamp_min(kMinAlpha), at::zeros_like(alpha));
      grads.depth_sum = per_alpha;
      grads.alpha = grads.alpha.defined() ? grads.alpha - per_alpha * depth : -per_alpha * depth;
    }
    const splat::InputGradients g = in.means.is_cuda() ? splat::cuda::backward(in, camera, settings, fwd, grads)
                                                       : splat::cpu::backward(in, camera, settings, fwd, grads);
    return {g.means,     g.scales,     g.rotations, g.covariances, g.opacities,
            g.features,  g.background, at::Tensor(), at::Tensor()};
  }
};

}  // namespace

Camera Camera::from_tensor(const at::Tensor& world_to_camera, double fx, double fy, double cx, double cy,
                           int64_t width, int64_t height, double near_plane, double far_plane) {
  TORCH_CHECK(world_to_camera.defined() && world_to_camera.dim() == 2 && world_to_camera.size(0) == 4 &&
                  world_to_camera.size(1) == 4 && at::isFloatingType(world_to_camera.scalar_type()),
              "sfgs::Camera: world_to_camera must be a floating (4, 4) tensor, got ", describe(world_to_camera));
  const at::Tensor host = world_to_camera.detach().to(at::kCPU, at::kDouble).contiguous();
  Camera c;
  std::copy(host.data_ptr<double>(), host.data_ptr<double>() + 16, c.world_to_camera.begin());
  c.fx = fx; c.fy = fy; c.cx = cx; c.cy = cy;
  c.width = width; c.height = height;
  c.near_plane = near_plane; c.far_plane = far_plane;
  return c;
}

Camera Camera::looking_forward(double focal, int64_t width, int64_t height) {
  Camera c;
  c.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  c.fx = c.fy = focal;
  c.cx = 0.5 * double(width);
  c.cy = 0.5 * double(height);
  c.width = width;
  c.height = height;
  return c;
}

RenderResult render(const Gaussians& gaussians, const at::Tensor& background, const Camera& camera,
                    const RenderOptions& options) {
  const CameraSpec spec = validated_camera(camera);
  const SplatInputs in = validated_inputs(gaussians, background, options);
  const bool dilate = options.low_pass || options.antialiased;
  const BackendSettings settings{splat::ProjectionSettings{dilate ? kLowPassVariancePx2 : 0.0, options.antialiased},
                                 options.deterministic};
  const auto optional = [](const at::Tensor& t) { return t.defined() ? c10::optional<at::Tensor>(t) : c10::nullopt; };
  const variable_list out =
      SplatFunction::apply(in.means, optional(in.scales), optional(in.rotations), optional(in.covariances),
                           in.opacities, in.features, in.background, spec, settings);
  RenderResult result;
  result.image = out[0];
  result.alpha = out[1];
  result.depth = out[2];
  result.radii = out[3];
  result.visible = out[3].select(1, 0) > 0;
  return result;
}

std::string camera_problem(const Camera& c) {
  std::ostringstream why;
  const auto& m = c.world_to_camera;
  for (double v : m)
    if (!std::isfinite(v)) {
      why << "world_to_camera must be finite, got an entry " << v;
      return why.str();
    }
  if (m[12] != 0 || m[13] != 0 || m[14] != 0 || m[15] != 1) {
    why << "the last row of world_to_camera must be (0, 0, 0, 1), got (" << m[12] << ", " << m[13] << ", " << m[14]
        << ", " << m[15] << ")";
    return why.str();
  }
  // The rotation block must be a proper rotation: R R^T = I within tolerance and det R = +1 (a singular, scaled or
  // mirroring matrix would project every point to the wrong place without any other sign of trouble).
  double deviation = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      double dot = 0;
      for (int k = 0; k < 3; ++k) dot += m[size_t(4 * i + k)] * m[size_t(4 * j + k)];
      deviation = std::max(deviation, std::abs(dot - (i == j ? 1.0 : 0.0)));
    }
  const double det = m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8]) +
                     m[2] * (m[4] * m[9] - m[5] * m[8]);
  if (deviation > kCameraRotationTolerance || det <= 0) {
    why << "the rotation part of world_to_camera must be orthonormal with determinant +1 (max |R R^T - I| <= "
        << kCameraRotationTolerance << "), got max |R R^T - I| = " << deviation << " and det R = " << det;
    return why.str();
  }
  if (!std::isfinite(c.fx) || !std::isfinite(c.fy) || !(c.fx > 0) || !(c.fy > 0)) {
    why << "focal lengths must be finite and positive, got fx = " << c.fx << ", fy = " << c.fy;
    return why.str();
  }
  if (!std::isfinite(c.cx) || !std::isfinite(c.cy)) {
    why << "the principal point must be finite, got (" << c.cx << ", " << c.cy << ")";
    return why.str();
  }
  if (c.width < 1 || c.height < 1 || c.width > kMaxImageSide || c.height > kMaxImageSide) {
    why << "image sides must be in [1, " << kMaxImageSide << "], got " << c.width << " x " << c.height;
    return why.str();
  }
  if (!std::isfinite(c.near_plane) || !(c.near_plane > 0)) {
    why << "near_plane must be finite and positive, got " << c.near_plane;
    return why.str();
  }
  if (!(c.far_plane > c.near_plane)) {
    why << "far_plane must exceed near_plane (" << c.near_plane << "), got " << c.far_plane;
    return why.str();
  }
  return "";
}

bool cuda_backend_available() { return splat::cuda::available(); }

}  // namespace sfgs
