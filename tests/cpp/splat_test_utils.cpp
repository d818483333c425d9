#include "splat_test_utils.h"
#include "ops/splat/constants.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <ATen/CPUGeneratorImpl.h>

namespace sfgs::testing {
namespace {

at::Tensor uniform(std::vector<int64_t> shape, double lo, double hi, at::Generator& gen) {
  return at::empty(shape, at::kDouble).uniform_(lo, hi, gen);
}

// Rotation about x, then y, then z (radians), as a 3x3 double tensor.
at::Tensor rotation_xyz(double ax, double ay, double az) {
  const at::Tensor rx =
      at::tensor({1.0, 0.0, 0.0, 0.0, std::cos(ax), -std::sin(ax), 0.0, std::sin(ax), std::cos(ax)}).view({3, 3});
  const at::Tensor ry =
      at::tensor({std::cos(ay), 0.0, std::sin(ay), 0.0, 1.0, 0.0, -std::sin(ay), 0.0, std::cos(ay)}).view({3, 3});
  const at::Tensor rz =
      at::tensor({std::cos(az), -std::sin(az), 0.0, std::sin(az), std::cos(az), 0.0, 0.0, 0.0, 1.0}).view({3, 3});
  return rz.matmul(ry).matmul(rx);
}

at::Tensor rotation_from_quaternions(const at::Tensor& quaternions) {
  const at::Tensor q = quaternions / quaternions.norm(2, 1, true);
  const at::Tensor w = q.select(1, 0), x = q.select(1, 1), y = q.select(1, 2), z = q.select(1, 3);
  return at::stack({1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y), 2 * (x * y + w * z),
                    1 - 2 * (x * x + z * z), 2 * (y * z - w * x), 2 * (x * z - w * y), 2 * (y * z + w * x),
                    1 - 2 * (x * x + y * y)},
                   1)
      .view({-1, 3, 3});
}

at::Tensor covariance_matrices(const Gaussians& g) {
  if (g.covariances.defined()) {
    const at::Tensor c = g.covariances;
    return at::stack({c.select(1, 0), c.select(1, 1), c.select(1, 2), c.select(1, 1), c.select(1, 3), c.select(1, 4),
                      c.select(1, 2), c.select(1, 4), c.select(1, 5)},
                     1)
        .view({-1, 3, 3});
  }
  const at::Tensor m = rotation_from_quaternions(g.rotations) * g.scales.unsqueeze(1);
  return m.matmul(m.transpose(1, 2));
}

}  // namespace

TestScene random_scene(const SceneSpec& spec, uint64_t seed, at::ScalarType dtype) {
  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  const int64_t n = spec.count;
  TestScene s;
  Camera& cam = s.camera;
  cam.width = spec.width;
  cam.height = spec.height;
  cam.fx = 1.1 * double(spec.width) + 3.0;
  cam.fy = 1.05 * double(spec.width) + 5.0;
  cam.cx = 0.45 * double(spec.width) + 1.3;
  cam.cy = 0.55 * double(spec.height) - 0.7;
  const at::Tensor rotation = rotation_xyz(0.1, -0.2, 0.15);
  const at::Tensor translation = at::tensor({0.3, -0.2, 0.5}, at::kDouble);
  at::Tensor view = at::eye(4, at::kDouble);
  view.slice(0, 0, 3).slice(1, 0, 3).copy_(rotation);
  view.slice(0, 0, 3).select(1, 3).copy_(translation);
  std::copy(view.data_ptr<double>(), view.data_ptr<double>() + 16, cam.world_to_camera.begin());

  // Place Gaussians by their pixel position and depth, then map back to world space.
  const at::Tensor z = uniform({n}, 2.5, 4.0, gen);
  const at::Tensor u = uniform({n}, 0.15 * spec.width, 0.85 * spec.width, gen);
  const at::Tensor v = uniform({n}, 0.15 * spec.height, 0.85 * spec.height, gen);
  const at::Tensor camera_points = at::stack({(u - cam.cx) * z / cam.fx, (v - cam.cy) * z / cam.fy, z}, 1);
  s.gaussians.means = (camera_points - translation).matmul(rotation);  // R^T (p - t), row-wise

  const at::Tensor footprint = uniform({n, 3}, spec.min_footprint_px, spec.max_footprint_px, gen);
  const at::Tensor scales = footprint * z.unsqueeze(1) / cam.fx;
  const at::Tensor quaternions = at::empty({n, 4}, at::kDouble).normal_(0.0, 1.0, gen);
  // Unnormalised on purpose: the op normalises inside.
  const at::Tensor rotations = quaternions * uniform({n, 1}, 0.5, 2.0, gen);
  if (spec.covariances) {
    Gaussians tmp;
    tmp.scales = scales;
    tmp.rotations = rotations;
    const at::Tensor c = covariance_matrices(tmp);
    s.gaussians.covariances =
        at::stack({c.select(1, 0).select(1, 0), c.select(1, 0).select(1, 1), c.select(1, 0).select(1, 2),
                   c.select(1, 1).select(1, 1), c.select(1, 1).select(1, 2), c.select(1, 2).select(1, 2)},
                  1);
  } else {
    s.gaussians.scales = scales;
    s.gaussians.rotations = rotations;
  }
  s.gaussians.opacities = uniform({n}, spec.min_opacity, spec.max_opacity, gen);
  s.gaussians.features = uniform({n, spec.channels}, 0.0, 1.0, gen);
  s.background = uniform({spec.channels}, 0.0, 1.0, gen);
  for (at::Tensor* t : {&s.gaussians.means, &s.gaussians.scales, &s.gaussians.rotations, &s.gaussians.covariances,
                        &s.gaussians.opacities, &s.gaussians.features, &s.background})
    if (t->defined()) *t = t->to(dtype).contiguous();
  return s;
}

ReferenceImage reference_render(const Gaussians& g, const at::Tensor& background, const Camera& cam,
                                const RenderOptions& options) {
  const auto opts = g.means.options();
  const at::Tensor view =
      at::tensor(std::vector<double>(cam.world_to_camera.begin(), cam.world_to_camera.end())).view({4, 4}).to(opts);
  const at::Tensor rotation = view.slice(0, 0, 3).slice(1, 0, 3);
  const at::Tensor translation = view.slice(0, 0, 3).select(1, 3);
  const at::Tensor p = g.means.matmul(rotation.t()) + translation;
  const at::Tensor x = p.select(1, 0), y = p.select(1, 1), z = p.select(1, 2);
  const at::Tensor camera_cov = rotation.matmul(covariance_matrices(g)).matmul(rotation.t());

  const double guard_x = kFovGuardFraction * 0.5 * double(cam.width) / cam.fx;
  const double guard_y = kFovGuardFraction * 0.5 * double(cam.height) / cam.fy;
  const at::Tensor tx = (x / z).clamp(-cam.cx / cam.fx - guard_x, (double(cam.width) - cam.cx) / cam.fx + guard_x);
  const at::Tensor ty = (y / z).clamp(-cam.cy / cam.fy - guard_y, (double(cam.height) - cam.cy) / cam.fy + guard_y);
  const at::Tensor zero = at::zeros_like(z);
  const at::Tensor jac =
      at::stack({cam.fx / z, zero, -cam.fx * tx / z, zero, cam.fy / z, -cam.fy * ty / z}, 1).view({-1, 2, 3});
  const at::Tensor cov2d = jac.matmul(camera_cov).matmul(jac.transpose(1, 2));
  const bool dilate = options.low_pass || options.antialiased;
  const double blur = dilate ? kLowPassVariancePx2 : 0.0;
  const at::Tensor a0 = cov2d.select(1, 0).select(1, 0), c0 = cov2d.select(1, 1).select(1, 1);
  const at::Tensor b = cov2d.select(1, 0).select(1, 1);
  const at::Tensor a = a0 + blur, c = c0 + blur;
  const at::Tensor det = a * c - b * b;
  at::Tensor opacity = g.opacities.reshape({-1});
  if (options.antialiased)
    opacity = opacity * at::sqrt(((a0 * c0 - b * b).clamp_min(0) / det).clamp_min(kMinCompensation * kMinCompensation));
  const at::Tensor ca = c / det, cb = -b / det, cc = a / det;
  const at::Tensor mx = cam.fx * x / z + cam.cx, my = cam.fy * y / z + cam.cy;
  const at::Tensor valid = (z >= cam.near_plane) & (z <= cam.far_plane) & (opacity >= kMinAlpha);

  const at::Tensor px = at::arange(cam.width, opts).add(kPixelCentre).repeat({cam.height});
  const at::Tensor py = at::arange(cam.height, opts).add(kPixelCentre).repeat_interleave(cam.width);
  const at::Tensor dx = px.unsqueeze(1) - mx.unsqueeze(0), dy = py.unsqueeze(1) - my.unsqueeze(0);
  const at::Tensor sigma = 0.5 * (ca * dx * dx + cc * dy * dy) + cb * dx * dy;
  const at::Tensor raw = opacity * at::exp(-sigma);
  at::Tensor alpha = raw.clamp_max(kMaxAlpha);
  const at::Tensor keep = (alpha >= kMinAlpha) & (sigma >= 0) & valid;
  alpha = at::where(keep, alpha, at::zeros_like(alpha));

  const at::Tensor order = std::get<1>(z.detach().sort(/*stable=*/true, 0, false));
  alpha = alpha.index_select(1, order);
  const at::Tensor before =
      at::cat({at::ones_like(alpha.narrow(1, 0, 1)), at::cumprod(1 - alpha, 1).narrow(1, 0, alpha.size(1) - 1)}, 1);
  const at::Tensor stop = ((before * (1 - alpha)) < kMinTransmittance) & (alpha > 0);
  const at::Tensor stopped = stop.to(at::kInt).cumsum(1) > 0;
  const at::Tensor used = at::where(stopped, at::zeros_like(alpha), alpha);
  const at::Tensor transmittance = at::cat({at::ones_like(used.narrow(1, 0, 1)), at::cumprod(1 - used, 1)}, 1);
  const at::Tensor weights = used * transmittance.narrow(1, 0, used.size(1));
  const at::Tensor final_t = transmittance.select(1, used.size(1));

  ReferenceImage r;
  const at::Tensor features = g.features.index_select(0, order);
  r.image = (weights.matmul(features) + final_t.unsqueeze(1) * background).view({cam.height, cam.width, -1});
  r.alpha = (1 - final_t).view({cam.height, cam.width});
  const at::Tensor depth_sum = weights.matmul(z.index_select(0, order)).view({cam.height, cam.width});
  r.depth = at::where(r.alpha > 0, depth_sum / r.alpha.clamp_min(kMinAlpha), at::zeros_like(depth_sum));

  const at::Tensor raw_kept = raw.detach().index_select(1, order);
  const at::Tensor active = (raw_kept > 0) & valid.index_select(0, order).unsqueeze(0);
  const at::Tensor to_min = ((raw_kept - kMinAlpha).abs() / kMinAlpha).masked_fill(~active, 1e9);
  const at::Tensor to_max = ((raw_kept - kMaxAlpha).abs() / kMaxAlpha).masked_fill(~active, 1e9);
  const at::Tensor next_t = (before.detach() * (1 - alpha.detach()));
  const at::Tensor to_stop =
      ((next_t - kMinTransmittance).abs() / kMinTransmittance).masked_fill(alpha.detach() <= 0, 1e9);
  r.threshold_margin =
      std::min({to_min.min().item<double>(), to_max.min().item<double>(), to_stop.min().item<double>()});
  return r;
}

TestScene smooth_random_scene(const SceneSpec& spec, uint64_t seed, const RenderOptions& options, double margin) {
  for (uint64_t attempt = 0; attempt < 200; ++attempt) {
    TestScene s = random_scene(spec, seed + 7919 * attempt);
    if (reference_render(s.gaussians, s.background, s.camera, options).threshold_margin >= margin) return s;
  }
  throw std::runtime_error("no random scene kept the requested distance from the thresholds");
}

LossWeights random_weights(int64_t height, int64_t width, int64_t channels, uint64_t seed, at::ScalarType dtype) {
  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  return LossWeights{uniform({height, width, channels}, -1.0, 1.0, gen).to(dtype),
                     uniform({height, width}, -1.0, 1.0, gen).to(dtype),
                     uniform({height, width}, -0.3, 0.3, gen).to(dtype)};
}

at::Tensor weighted_loss(const at::Tensor& image, const at::Tensor& alpha, const at::Tensor& depth,
                         const LossWeights& w) {
  return (image * w.image).sum() + (alpha * w.alpha).sum() + (depth * w.depth).sum();
}

at::Tensor finite_difference(const std::function<double()>& f, at::Tensor param, double step) {
  at::Tensor grad = at::zeros_like(param);
  at::Tensor flat = param.detach().view({-1});
  at::Tensor out = grad.view({-1});
  for (int64_t i = 0; i < flat.numel(); ++i) {
    const double original = flat[i].item<double>();
    flat[i] = original + step;
    const double plus = f();
    flat[i] = original - step;
    const double minus = f();
    flat[i] = original;
    out[i] = (plus - minus) / (2 * step);
  }
  return grad;
}

double relative_error(const at::Tensor& a, const at::Tensor& b) {
  const double diff = (a.to(at::kDouble) - b.to(at::kDouble)).norm().item<double>();
  const double ref = b.to(at::kDouble).norm().item<double>();
  if (ref == 0) return diff;
  return diff / ref;
}

std::vector<std::pair<std::string, at::Tensor*>> differentiable_inputs(TestScene& s) {
  std::vector<std::pair<std::string, at::Tensor*>> out;
  Gaussians& g = s.gaussians;
  for (auto& [name, t] : std::vector<std::pair<std::string, at::Tensor*>>{{"means", &g.means},
                                                                          {"scales", &g.scales},
                                                                          {"rotations", &g.rotations},
                                                                          {"covariances", &g.covariances},
                                                                          {"opacities", &g.opacities},
                                                                          {"features", &g.features},
                                                                          {"background", &s.background}})
    if (t->defined()) out.emplace_back(name, t);
  return out;
}

}  // namespace sfgs::testing
