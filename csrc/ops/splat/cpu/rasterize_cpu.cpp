// CPU reference backend of the splatting op, float and double: runs the stages of stages_cpu.h in order and keeps
// what backward needs in a cpu::ForwardContext.
#include <ATen/ATen.h>

#include "ops/splat/cpu/stages_cpu.h"
#include "ops/splat/validation.h"

namespace sfgs::splat::cpu {
namespace {

template <typename T> TileLists<T> tile_lists(const ForwardContext& c) {
  return TileLists<T>{c.projected.data_ptr<T>(), c.isect_gaussian.data_ptr<int64_t>(),
                      c.tile_offsets.data_ptr<int64_t>(), c.tile_order.data_ptr<int64_t>()};
}

template <typename T>
Forward forward_typed(const SplatInputs& in, const Camera& camera, const BackendSettings& settings) {
  check_background_finite(in.background);
  check_opacities(in.opacities);
  const SplatScene<T> scene = make_scene<T>(in, camera, settings);
  const TileGrid grid = make_grid(int(camera.width), int(camera.height));
  Projection projection = project(scene, grid, in.means.options());
  const Binning binning = bin<T>(projection, grid);

  Forward out;
  ForwardContext& c = out.context;
  c.projected = projection.projected;
  c.gaussian_offsets = binning.gaussian_offsets;
  c.isect_gaussian = binning.isect_gaussian;
  c.tile_offsets = binning.tile_offsets;
  c.tile_order = binning.tile_order;
  const BlendOutputs blended = blend_forward(scene, grid, tile_lists<T>(c));
  c.final_transmittance = blended.final_transmittance;
  c.contributors = blended.contributors;
  out.outputs = ForwardOutputs{blended.image, blended.alpha, blended.depth, projection.radii};
  return out;
}

template <typename T>
InputGradients backward_typed(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                              const ForwardContext& c, const OutputGradients& grads) {
  const SplatScene<T> scene = make_scene<T>(in, camera, settings);
  const TileGrid grid = make_grid(int(camera.width), int(camera.height));
  const int64_t h = grid.height, w = grid.width;
  const auto real = in.means.options();
  const auto or_zeros = [&](const at::Tensor& g, at::IntArrayRef sizes) {
    return g.defined() ? g.contiguous() : at::zeros(sizes, real);
  };
  const at::Tensor grad_image = or_zeros(grads.image, {h, w, int64_t(scene.channels)});
  const at::Tensor grad_alpha = or_zeros(grads.alpha, {h, w});
  const at::Tensor grad_depth = or_zeros(grads.depth_sum, {h, w});

  InputGradients out;
  for (auto [gradient, input] : {std::pair{&out.means, &in.means},
                                 {&out.scales, &in.scales},
                                 {&out.rotations, &in.rotations},
                                 {&out.covariances, &in.covariances},
                                 {&out.opacities, &in.opacities},
                                 {&out.features, &in.features},
                                 {&out.background, &in.background}})
    if (input->defined()) *gradient = at::zeros_like(*input);
  const auto data = [](const at::Tensor& t) { return t.defined() ? t.data_ptr<T>() : nullptr; };
  const Gradients<T> arrays{data(out.means),     data(out.scales),   data(out.rotations), data(out.covariances),
                            data(out.opacities), data(out.features), data(out.background)};
  blend_backward(scene, grid, tile_lists<T>(c), c.gaussian_offsets.data_ptr<int64_t>(), c.isect_gaussian.numel(),
                 c.final_transmittance.data_ptr<T>(), c.contributors.data_ptr<int32_t>(),
                 OutputGradientArrays<T>{grad_image.data_ptr<T>(), grad_alpha.data_ptr<T>(), grad_depth.data_ptr<T>()},
                 arrays);
  return out;
}

}  // namespace

Forward forward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings) {
  if (in.means.scalar_type() == at::kDouble) return forward_typed<double>(in, camera, settings);
  return forward_typed<float>(in, camera, settings);
}

InputGradients backward(const SplatInputs& in, const Camera& camera, const BackendSettings& settings,
                        const ForwardContext& context, const OutputGradients& grads) {
  if (in.means.scalar_type() == at::kDouble) return backward_typed<double>(in, camera, settings, context, grads);
  return backward_typed<float>(in, camera, settings, context, grads);
}

}  // namespace sfgs::splat::cpu
