#include "fit/silhouette.h"

#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "body/parts.h"
#include "body/skeleton.h"
#include "fit/constants.h"
#include "ops/splat/constants.h"
#include "data/image_io.h"
#include "fit/fit_losses.h"

namespace sfgs::fit {
namespace {

// One pass of the 1-D squared distance transform (the lower envelope of parabolas) over n values with stride.
void squared_distance_1d(float* f, int64_t n, int64_t stride, std::vector<float>& d, std::vector<int64_t>& v,
                         std::vector<float>& z) {
  const float inf = std::numeric_limits<float>::infinity();
  int64_t k = 0;
  v[0] = 0;
  z[0] = -inf;
  z[1] = inf;
  for (int64_t q = 1; q < n; ++q) {
    float s = 0;
    while (true) {
      const float fq = f[q * stride], fv = f[v[size_t(k)] * stride];
      s = ((fq + float(q * q)) - (fv + float(v[size_t(k)] * v[size_t(k)]))) / float(2 * q - 2 * v[size_t(k)]);
      if (s > z[size_t(k)] || k == 0) break;
      --k;
    }
    if (s <= z[size_t(k)]) s = z[size_t(k)];
    ++k;
    v[size_t(k)] = q;
    z[size_t(k)] = s;
    z[size_t(k + 1)] = inf;
  }
  k = 0;
  for (int64_t q = 0; q < n; ++q) {
    while (z[size_t(k + 1)] < float(q)) ++k;
    const float diff = float(q - v[size_t(k)]);
    d[size_t(q)] = diff * diff + f[v[size_t(k)] * stride];
  }
  for (int64_t q = 0; q < n; ++q) f[q * stride] = d[size_t(q)];
}

}  // namespace

at::Tensor distance_to_mask(const at::Tensor& mask) {
  TORCH_CHECK(mask.dim() == 2, "distance_to_mask: expected an (H, W) mask, got ", mask.sizes());
  const int64_t h = mask.size(0), w = mask.size(1);
  // Squared distances are finite stand-ins for infinity so that the parabola intersections stay finite.
  const float far = float(4 * (h + w) * (h + w));
  at::Tensor f = at::where(mask.to(at::kCPU, at::kBool), at::zeros({h, w}), at::full({h, w}, far)).contiguous();
  float* p = f.data_ptr<float>();
  const int64_t n = std::max(h, w);
  std::vector<float> d(static_cast<size_t>(n)), z(static_cast<size_t>(n + 1));
  std::vector<int64_t> v(static_cast<size_t>(n));
  for (int64_t x = 0; x < w; ++x) squared_distance_1d(p + x, h, w, d, v, z);
  for (int64_t y = 0; y < h; ++y) squared_distance_1d(p + y * w, w, 1, d, v, z);
  return f.sqrt();
}

SilhouetteTargets silhouette_targets(const FitInput& input, const at::TensorOptions& options) {
  SilhouetteTargets t;
  const int64_t batch = int64_t(input.frames.size());
  bool any = false;
  for (const FitFrame& f : input.frames) {
    if (f.width != input.frames[0].width || f.height != input.frames[0].height) return t;
    any = any || !f.mask_path.empty();
  }
  if (!any) return t;
  t.width = double(input.frames[0].width);
  t.height = double(input.frames[0].height);
  const double scale = std::min(1.0, double(kFitSilhouetteSide) / std::max(t.width, t.height));
  const int64_t rh = std::max<int64_t>(1, int64_t(std::lround(t.height * scale)));
  const int64_t rw = std::max<int64_t>(1, int64_t(std::lround(t.width * scale)));
  at::Tensor distance = at::zeros({batch, 1, rh, rw});
  at::Tensor boundary = at::zeros({batch, kFitSilhouetteBoundarySamples, 2});
  at::Tensor boundary_weight = at::zeros({batch, kFitSilhouetteBoundarySamples});
  at::Tensor frame_weight = at::zeros({batch});
  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(kFitSilhouetteSeed);
  for (int64_t b = 0; b < batch; ++b) {
    const FitFrame& f = input.frames[size_t(b)];
    if (f.mask_path.empty()) continue;
    const at::Tensor mask = data::read_mask(
        f.mask_path, f.mask_white_person ? data::MaskEncoding::kWhitePerson : data::MaskEncoding::kBlackPerson);
    TORCH_CHECK(mask.size(0) == f.height && mask.size(1) == f.width, "sfgs fit: mask '", f.mask_path, "' is ",
                mask.size(1), " x ", mask.size(0), " but frame ", f.number, " is ", f.width, " x ", f.height);
    if (mask.sum().item<double>() < 1) continue;  // nobody in view: no silhouette to match
    const at::Tensor reduced =
        at::upsample_bilinear2d(mask.view({1, 1, f.height, f.width}), {rh, rw}, false)[0][0] > 0.5;
    distance[b][0] = distance_to_mask(reduced) / scale;
    // The boundary: mask pixels with a pixel outside among their four neighbours.
    const at::Tensor inside = mask > 0.5;
    const at::Tensor padded = at::constant_pad_nd(inside, {1, 1, 1, 1}, 0);
    const at::Tensor interior = padded.slice(0, 0, -2).slice(1, 1, -1) & padded.slice(0, 2).slice(1, 1, -1) &
                                padded.slice(0, 1, -1).slice(1, 0, -2) & padded.slice(0, 1, -1).slice(1, 2);
    const at::Tensor edge = (inside & ~interior).nonzero();  // (P, 2) rows, columns
    const int64_t take = std::min<int64_t>(edge.size(0), kFitSilhouetteBoundarySamples);
    const at::Tensor chosen = edge.index_select(0, at::randperm(edge.size(0), gen).narrow(0, 0, take));
    boundary[b]
        .narrow(0, 0, take)
        .copy_(at::stack({chosen.select(1, 1), chosen.select(1, 0)}, 1).to(at::kFloat) + kPixelCentre);
    boundary_weight[b].narrow(0, 0, take).fill_(1.0);
    frame_weight[b] = 1.0;
  }
  t.outside_distance = distance.to(options);
  t.boundary = boundary.to(options);
  t.boundary_weight = boundary_weight.to(options);
  t.frame_weight = frame_weight.to(options);
  return t;
}

at::Tensor silhouette_vertex_sample(const body::SmplxModelData& model, int64_t count) {
  const at::Tensor dominant = body::dominant_joints(model.weights.to(at::kDouble));
  const at::Tensor excluded = (dominant >= body::smplx_joint::kLeftEye) | (dominant == body::smplx_joint::kLeftWrist) |
                              (dominant == body::smplx_joint::kRightWrist);
  const at::Tensor eligible = (~excluded).nonzero().squeeze(1);
  const int64_t step = std::max<int64_t>(1, eligible.size(0) / std::max<int64_t>(count, 1));
  return eligible.slice(0, 0, eligible.size(0), step).contiguous();
}

at::Tensor silhouette_loss(const at::Tensor& projected, const SilhouetteTargets& targets, const at::Tensor& person_size,
                           double sigma) {
  const at::Tensor size = person_size.view({-1, 1});
  // Inside: the distance transform at each projection (grid_sample's coordinates span the image in [-1, 1]).
  const at::Tensor grid =
      at::stack({projected.select(2, 0) / targets.width * 2 - 1, projected.select(2, 1) / targets.height * 2 - 1}, 2)
          .unsqueeze(1);
  const at::Tensor outside = at::grid_sampler_2d(targets.outside_distance, grid, 0, 1, false).squeeze(1).squeeze(1);
  const at::Tensor inside_term = geman_mcclure((outside / size).square(), sigma).mean(1);
  // Covered: each boundary sample's nearest projected vertex.
  const at::Tensor nearest = std::get<0>(at::cdist(targets.boundary, projected).min(2));  // (B, M)
  const at::Tensor cover = (geman_mcclure((nearest / size).square(), sigma) * targets.boundary_weight).sum(1) /
                           targets.boundary_weight.sum(1).clamp_min(1);
  const at::Tensor per_frame = (inside_term + cover) * targets.frame_weight;
  return per_frame.sum() / targets.frame_weight.sum().clamp_min(1);
}

}  // namespace sfgs::fit
