// CPU reference backend of the splatting op: float and double, parallel over Gaussians and tiles with
// at::parallel_for, deterministic for any thread count (every reduction has a fixed order).
//
// Pipeline: project each Gaussian (pair_math.h) -> count and emit its (tile, depth) intersections with the exact
// ellipse/tile test -> counting sort by tile, then sort each tile by (depth, Gaussian) -> blend front to back.
// Both blends run tile by tile and Gaussian by Gaussian over only the pixels each Gaussian can reach. Backward
// replays each pixel's blend (re-evaluating, not dividing, its transmittances), walks it back to front, writes each
// pair's gradient into that intersection's own slot, and sums the slots per Gaussian.
#include <algorithm>
#include <array>
#include <numeric>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "splat/backend.h"

namespace sfgs::splat::cpu {
namespace {

// Layout of one intersection's gradient slot, followed by the C feature gradients.
enum SlotField { kGradMeanX, kGradMeanY, kGradConicA, kGradConicB, kGradConicC, kGradOpacity, kGradDepth, kSlotWidth };
// Indices into ForwardOutputs::saved.
enum SavedField { kSavedProjected, kSavedGaussianOffsets, kSavedIsectGaussian, kSavedTileOffsets, kSavedTileOrder,
                  kSavedFinalT, kSavedContributors, kSavedCount };

template <typename T> Mat3<T> world_covariance(const SplatInputs& in, int64_t i, bool& usable) {
  Mat3<T> cov(T(0));
  if (in.uses_covariances()) {
    cov = unpack_covariance(in.covariances.data_ptr<T>() + 6 * i);
    usable = covariance_usable(cov);
  } else {
    const T* s = in.scales.data_ptr<T>() + 3 * i;
    const T* q = in.rotations.data_ptr<T>() + 4 * i;
    usable = covariance_from_scale_rotation(Vec3<T>(s[0], s[1], s[2]), Vec4<T>(q[0], q[1], q[2], q[3]), cov);
  }
  return cov;
}

// Pixels a projected Gaussian can reach with alpha >= kMinAlpha, widened by one pixel so rounding at the ellipse's
// edge can never drop a pixel the pair test would keep: every pixel outside has sigma well above the level.
template <typename T> PixelRect reachable_pixels(const ProjectedGaussian<T>& g, int width, int height) {
  const T det = g.conic[0] * g.conic[2] - g.conic[1] * g.conic[1];
  PixelRect r = pixel_rect(g, g.conic[2] / det, g.conic[0] / det, width, height);
  r.x0 = std::max(0, r.x0 - 1);
  r.y0 = std::max(0, r.y0 - 1);
  r.x1 = std::min(width - 1, r.x1 + 1);
  r.y1 = std::min(height - 1, r.y1 + 1);
  return r;
}

// One entry of a tile's depth-ordered list, with the part of the tile it can reach.
template <typename T> struct TileEntry {
  ProjectedGaussian<T> g;
  int64_t slot;  // emission slot (gradient slot) of this intersection
  int x0, y0, x1, y1;  // reachable pixels inside the tile, tile-local
};

struct TileGrid {
  int width, height, tiles_x, tiles_y;
  int64_t count() const { return int64_t(tiles_x) * tiles_y; }
};

TileGrid make_grid(const CameraSpec& c) {
  return TileGrid{c.width, c.height, (c.width + kTileSize - 1) / kTileSize, (c.height + kTileSize - 1) / kTileSize};
}

// The tile's list entries [begin, end) with their reachable pixels clipped to the tile; entries reaching none of the
// tile's pixels are kept (as empty rectangles) so list positions stay those of the forward pass.
template <typename T>
void gather_tile(const TileGrid& grid, int64_t tile, const int64_t* order, int64_t begin, int64_t end,
                 const int64_t* isect_gaussian, const T* projected, std::vector<TileEntry<T>>& out) {
  const int tx0 = int(tile % grid.tiles_x) * kTileSize, ty0 = int(tile / grid.tiles_x) * kTileSize;
  out.clear();
  for (int64_t k = begin; k < end; ++k) {
    TileEntry<T> e;
    e.slot = order[k];
    e.g = load_projected(projected + isect_gaussian[e.slot] * kProjectedWidth);
    const PixelRect r = reachable_pixels(e.g, grid.width, grid.height);
    e.x0 = std::max(r.x0 - tx0, 0);
    e.y0 = std::max(r.y0 - ty0, 0);
    e.x1 = std::min(r.x1 - tx0, kTileSize - 1);
    e.y1 = std::min(r.y1 - ty0, kTileSize - 1);
    out.push_back(e);
  }
}

template <typename T> bool features_finite(const T* f, int64_t channels) {
  for (int64_t k = 0; k < channels; ++k)
    if (!is_finite(f[k])) return false;
  return true;
}

template <typename T>
ForwardOutputs forward_typed(const SplatInputs& in, const CameraSpec& spec, const BackendSettings& settings) {
  const PinholeCamera<T> cam = to_pinhole<T>(spec);
  const TileGrid grid = make_grid(spec);
  const int64_t n = in.means.size(0);
  const int64_t channels = in.features.size(1);
  const auto real = in.means.options();
  const auto i64 = real.dtype(at::kLong);

  at::Tensor projected = at::zeros({n, kProjectedWidth}, real);
  at::Tensor radii = at::zeros({n, 2}, real.dtype(at::kInt));
  std::vector<PixelRect> tiles(n);
  std::vector<int64_t> tiles_touched(n, 0);
  const T* means = in.means.data_ptr<T>();
  const T* opacities = in.opacities.data_ptr<T>();
  const T* features = in.features.data_ptr<T>();
  T* proj = projected.data_ptr<T>();
  int32_t* rad = radii.data_ptr<int32_t>();

  at::parallel_for(0, n, 256, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      bool usable = false;
      const Mat3<T> cov = world_covariance<T>(in, i, usable);
      ProjectedGaussian<T> g;
      PixelRect pixels;
      Vec2<T> radius;
      if (!usable || !features_finite(features + i * channels, channels) ||
          !project_gaussian(cam, settings.projection, Vec3<T>(means[3 * i], means[3 * i + 1], means[3 * i + 2]), cov,
                            opacities[i], g, pixels, radius))
        continue;
      const PixelRect t = tile_rect(pixels);
      int64_t touched = 0;
      for (int ty = t.y0; ty <= t.y1; ++ty)
        for (int tx = t.x0; tx <= t.x1; ++tx) touched += tile_touches(g, tx, ty, grid.width, grid.height);
      if (touched == 0) continue;
      tiles[i] = t;
      tiles_touched[i] = touched;
      store_projected(g, proj + i * kProjectedWidth);
      rad[2 * i] = pixel_radius(radius[0]);
      rad[2 * i + 1] = pixel_radius(radius[1]);
    }
  });

  // Emission order is Gaussian-major: Gaussian i owns slots [gaussian_offsets[i], gaussian_offsets[i+1]).
  at::Tensor gaussian_offsets = at::empty({n + 1}, i64);
  int64_t* goff = gaussian_offsets.data_ptr<int64_t>();
  goff[0] = 0;
  for (int64_t i = 0; i < n; ++i) goff[i + 1] = goff[i] + tiles_touched[i];
  const int64_t n_isect = goff[n];

  at::Tensor isect_gaussian = at::empty({n_isect}, i64);
  std::vector<int64_t> isect_tile(n_isect);
  int64_t* ig = isect_gaussian.data_ptr<int64_t>();
  at::parallel_for(0, n, 256, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      if (tiles_touched[i] == 0) continue;
      const ProjectedGaussian<T> g = load_projected(proj + i * kProjectedWidth);
      int64_t slot = goff[i];
      const PixelRect& t = tiles[i];
      for (int ty = t.y0; ty <= t.y1; ++ty)
        for (int tx = t.x0; tx <= t.x1; ++tx)
          if (tile_touches(g, tx, ty, grid.width, grid.height)) {
            isect_tile[slot] = int64_t(ty) * grid.tiles_x + tx;
            ig[slot++] = i;
          }
    }
  });

  // Counting sort by tile keeps Gaussian order within a tile; the per-tile sort by depth is then stable, so ties
  // resolve by Gaussian index exactly as a stable (tile, depth) radix sort does.
  const int64_t n_tiles = grid.count();
  at::Tensor tile_offsets = at::zeros({n_tiles + 1}, i64);
  int64_t* toff = tile_offsets.data_ptr<int64_t>();
  for (int64_t s = 0; s < n_isect; ++s) ++toff[isect_tile[s] + 1];
  for (int64_t t = 0; t < n_tiles; ++t) toff[t + 1] += toff[t];
  at::Tensor tile_order = at::empty({n_isect}, i64);
  int64_t* order = tile_order.data_ptr<int64_t>();
  {
    std::vector<int64_t> cursor(toff, toff + n_tiles);
    for (int64_t s = 0; s < n_isect; ++s) order[cursor[isect_tile[s]]++] = s;
  }
  at::parallel_for(0, n_tiles, 16, [&](int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t)
      std::stable_sort(order + toff[t], order + toff[t + 1], [&](int64_t a, int64_t b) {
        return proj[ig[a] * kProjectedWidth + kDepth] < proj[ig[b] * kProjectedWidth + kDepth];
      });
  });

  const int64_t h = grid.height, w = grid.width;
  at::Tensor image = at::empty({h, w, channels}, real);
  at::Tensor alpha = at::empty({h, w}, real);
  at::Tensor expected_depth = at::empty({h, w}, real);
  at::Tensor final_t = at::empty({h, w}, real);
  at::Tensor contributors = at::empty({h, w}, real.dtype(at::kInt));
  T* img = image.data_ptr<T>();
  T* alp = alpha.data_ptr<T>();
  T* dep = expected_depth.data_ptr<T>();
  T* fin = final_t.data_ptr<T>();
  int32_t* con = contributors.data_ptr<int32_t>();
  const T* bg = in.background.data_ptr<T>();

  // Tile by tile, Gaussian by Gaussian over only the pixels each can reach: per pixel this is exactly the front-to-back
  // loop over the tile's list (same pairs, same order, same arithmetic), without visiting pairs that must be skipped.
  constexpr int kTilePixels = kTileSize * kTileSize;
  at::parallel_for(0, n_tiles, 1, [&](int64_t begin, int64_t end) {
    std::vector<TileEntry<T>> entries;
    std::vector<T> colour(size_t(kTilePixels * channels));
    std::array<T, kTilePixels> transmittance, depth;
    std::array<int32_t, kTilePixels> last;
    std::array<bool, kTilePixels> done;
    for (int64_t tile = begin; tile < end; ++tile) {
      const int tx0 = int(tile % grid.tiles_x) * kTileSize, ty0 = int(tile / grid.tiles_x) * kTileSize;
      const int tw = std::min<int>(kTileSize, int(w) - tx0), th = std::min<int>(kTileSize, int(h) - ty0);
      gather_tile(grid, tile, order, toff[tile], toff[tile + 1], ig, proj, entries);
      std::fill(colour.begin(), colour.end(), T(0));
      transmittance.fill(T(1));
      depth.fill(T(0));
      last.fill(0);
      done.fill(false);
      int remaining = tw * th;
      for (size_t k = 0; k < entries.size() && remaining > 0; ++k) {
        const TileEntry<T>& e = entries[k];
        const T* f = features + ig[e.slot] * channels;
        for (int ly = e.y0; ly <= std::min(e.y1, th - 1); ++ly)
          for (int lx = e.x0; lx <= std::min(e.x1, tw - 1); ++lx) {
            const int p = ly * kTileSize + lx;
            if (done[p]) continue;
            PairAlpha<T> pair;
            if (!pair_alpha(e.g, T(tx0 + lx) + T(kPixelCentre), T(ty0 + ly) + T(kPixelCentre), pair)) continue;
            const T next = transmittance[p] * (T(1) - pair.alpha);
            if (next < T(kMinTransmittance)) {
              done[p] = true;
              --remaining;
              continue;
            }
            const T weight = pair.alpha * transmittance[p];
            T* c = colour.data() + p * channels;
            for (int64_t ch = 0; ch < channels; ++ch) c[ch] += weight * f[ch];
            depth[p] += weight * e.g.depth;
            transmittance[p] = next;
            last[p] = int32_t(k + 1);
          }
      }
      for (int ly = 0; ly < th; ++ly)
        for (int lx = 0; lx < tw; ++lx) {
          const int p = ly * kTileSize + lx;
          const int64_t pix = int64_t(ty0 + ly) * w + (tx0 + lx);
          for (int64_t ch = 0; ch < channels; ++ch)
            img[pix * channels + ch] = colour[size_t(p * channels + ch)] + transmittance[p] * bg[ch];
          alp[pix] = T(1) - transmittance[p];
          dep[pix] = expected_depth_of(depth[p], T(1) - transmittance[p]);
          fin[pix] = transmittance[p];
          con[pix] = last[p];
        }
    }
  });

  ForwardOutputs out;
  out.image = image;
  out.alpha = alpha;
  out.depth = expected_depth;
  out.radii = radii;
  out.saved.resize(kSavedCount);
  out.saved[kSavedProjected] = projected;
  out.saved[kSavedGaussianOffsets] = gaussian_offsets;
  out.saved[kSavedIsectGaussian] = isect_gaussian;
  out.saved[kSavedTileOffsets] = tile_offsets;
  out.saved[kSavedTileOrder] = tile_order;
  out.saved[kSavedFinalT] = final_t;
  out.saved[kSavedContributors] = contributors;
  return out;
}

// One blended pair remembered while replaying a pixel front to back.
template <typename T> struct ReplayedPair {
  int64_t slot;  // emission slot = gradient slot of this intersection
  PairAlpha<T> pair;
  T transmittance;  // before this pair
};

template <typename T>
InputGradients backward_typed(const SplatInputs& in, const CameraSpec& spec, const BackendSettings& settings,
                              const ForwardOutputs& fwd, const OutputGradients& grads) {
  const PinholeCamera<T> cam = to_pinhole<T>(spec);
  const TileGrid grid = make_grid(spec);
  const int64_t n = in.means.size(0);
  const int64_t channels = in.features.size(1);
  const int64_t h = grid.height, w = grid.width;
  const auto real = in.means.options();

  const at::Tensor grad_image = grads.image.defined() ? grads.image.contiguous() : at::zeros({h, w, channels}, real);
  const at::Tensor grad_alpha = grads.alpha.defined() ? grads.alpha.contiguous() : at::zeros({h, w}, real);
  const at::Tensor grad_depth = grads.depth_sum.defined() ? grads.depth_sum.contiguous() : at::zeros({h, w}, real);
  const T* gimg = grad_image.data_ptr<T>();
  const T* galp = grad_alpha.data_ptr<T>();
  const T* gdep = grad_depth.data_ptr<T>();

  const T* proj = fwd.saved[kSavedProjected].data_ptr<T>();
  const int64_t* goff = fwd.saved[kSavedGaussianOffsets].data_ptr<int64_t>();
  const int64_t* ig = fwd.saved[kSavedIsectGaussian].data_ptr<int64_t>();
  const int64_t* toff = fwd.saved[kSavedTileOffsets].data_ptr<int64_t>();
  const int64_t* order = fwd.saved[kSavedTileOrder].data_ptr<int64_t>();
  const T* fin = fwd.saved[kSavedFinalT].data_ptr<T>();
  const int32_t* con = fwd.saved[kSavedContributors].data_ptr<int32_t>();
  const T* features = in.features.data_ptr<T>();
  const T* bg = in.background.data_ptr<T>();

  const int64_t n_isect = fwd.saved[kSavedIsectGaussian].numel();
  const int64_t slot_width = kSlotWidth + channels;
  std::vector<T> slots(size_t(n_isect * slot_width), T(0));
  const int64_t n_tiles = grid.count();
  std::vector<T> background_partial(size_t(n_tiles * channels), T(0));

  at::parallel_for(0, n_tiles, 1, [&](int64_t begin, int64_t end) {
    constexpr int kTilePixels = kTileSize * kTileSize;
    std::vector<TileEntry<T>> entries;
    std::vector<std::vector<ReplayedPair<T>>> replay(kTilePixels);
    std::array<T, kTilePixels> transmittance;
    for (int64_t tile = begin; tile < end; ++tile) {
      const int tx0 = int(tile % grid.tiles_x) * kTileSize, ty0 = int(tile / grid.tiles_x) * kTileSize;
      const int tw = std::min<int>(kTileSize, int(w) - tx0), th = std::min<int>(kTileSize, int(h) - ty0);
      T* bg_partial = background_partial.data() + tile * channels;
      // Replay the forward pass (same pairs, same products), remembering each pixel's blended pairs.
      int32_t longest = 0;
      for (int ly = 0; ly < th; ++ly)
        for (int lx = 0; lx < tw; ++lx) longest = std::max(longest, con[int64_t(ty0 + ly) * w + tx0 + lx]);
      gather_tile(grid, tile, order, toff[tile], toff[tile] + longest, ig, proj, entries);
      for (auto& r : replay) r.clear();
      transmittance.fill(T(1));
      for (size_t k = 0; k < entries.size(); ++k) {
        const TileEntry<T>& e = entries[k];
        for (int ly = e.y0; ly <= std::min(e.y1, th - 1); ++ly)
          for (int lx = e.x0; lx <= std::min(e.x1, tw - 1); ++lx) {
            if (int32_t(k) >= con[int64_t(ty0 + ly) * w + tx0 + lx]) continue;
            const int p = ly * kTileSize + lx;
            PairAlpha<T> pair;
            if (!pair_alpha(e.g, T(tx0 + lx) + T(kPixelCentre), T(ty0 + ly) + T(kPixelCentre), pair)) continue;
            replay[size_t(p)].push_back(ReplayedPair<T>{e.slot, pair, transmittance[p]});
            transmittance[p] *= T(1) - pair.alpha;
          }
      }
      // Walk each pixel's pairs back to front.
      for (int ly = 0; ly < th; ++ly)
        for (int lx = 0; lx < tw; ++lx) {
          const int64_t pix = int64_t(ty0 + ly) * w + tx0 + lx;
          const T* g_colour = gimg + pix * channels;
          const T final_transmittance = fin[pix];
          for (int64_t c = 0; c < channels; ++c) bg_partial[c] += final_transmittance * g_colour[c];
          T behind_colour = T(0);
          for (int64_t c = 0; c < channels; ++c) behind_colour += final_transmittance * bg[c] * g_colour[c];
          T behind_depth = T(0);
          const auto& pairs = replay[size_t(ly * kTileSize + lx)];
          for (auto it = pairs.rbegin(); it != pairs.rend(); ++it) {
            const int64_t gi = ig[it->slot];
            const ProjectedGaussian<T> g = load_projected(proj + gi * kProjectedWidth);
            const T* f = features + gi * channels;
            T* slot = slots.data() + it->slot * slot_width;
            const T weight = it->pair.alpha * it->transmittance;
            T colour_dot = T(0);
            for (int64_t c = 0; c < channels; ++c) {
              slot[kSlotWidth + c] += weight * g_colour[c];
              colour_dot += f[c] * g_colour[c];
            }
            slot[kGradDepth] += weight * gdep[pix];
            const T grad_pair_alpha =
                composite_grad_alpha(it->pair.alpha, it->transmittance, colour_dot, behind_colour, g.depth, gdep[pix],
                                     behind_depth, final_transmittance, galp[pix]);
            Vec2<T> grad_mean(T(0));
            Vec3<T> grad_conic(T(0));
            T grad_opacity = T(0);
            pair_alpha_vjp(g, it->pair, grad_pair_alpha, grad_mean, grad_conic, grad_opacity);
            slot[kGradMeanX] += grad_mean[0];
            slot[kGradMeanY] += grad_mean[1];
            slot[kGradConicA] += grad_conic[0];
            slot[kGradConicB] += grad_conic[1];
            slot[kGradConicC] += grad_conic[2];
            slot[kGradOpacity] += grad_opacity;
            behind_colour += weight * colour_dot;
            behind_depth += weight * g.depth;
          }
        }
    }
  });

  InputGradients out;
  out.means = at::zeros_like(in.means);
  out.opacities = at::zeros_like(in.opacities);
  out.features = at::zeros_like(in.features);
  if (in.uses_covariances()) {
    out.covariances = at::zeros_like(in.covariances);
  } else {
    out.scales = at::zeros_like(in.scales);
    out.rotations = at::zeros_like(in.rotations);
  }
  T* g_means = out.means.data_ptr<T>();
  T* g_opac = out.opacities.data_ptr<T>();
  T* g_feat = out.features.data_ptr<T>();
  const T* means = in.means.data_ptr<T>();
  const T* opacities = in.opacities.data_ptr<T>();

  at::parallel_for(0, n, 256, [&](int64_t begin, int64_t end) {
    std::vector<T> sum(static_cast<size_t>(slot_width));
    for (int64_t i = begin; i < end; ++i) {
      if (goff[i] == goff[i + 1]) continue;
      std::fill(sum.begin(), sum.end(), T(0));
      for (int64_t s = goff[i]; s < goff[i + 1]; ++s)
        for (int64_t k = 0; k < slot_width; ++k) sum[k] += slots[s * slot_width + k];
      for (int64_t c = 0; c < channels; ++c) g_feat[i * channels + c] = sum[kSlotWidth + c];
      bool usable = false;
      const Mat3<T> cov = world_covariance<T>(in, i, usable);
      Vec3<T> grad_mean;
      Mat3<T> grad_cov;
      T grad_opacity;
      project_gaussian_vjp(cam, settings.projection, Vec3<T>(means[3 * i], means[3 * i + 1], means[3 * i + 2]), cov,
                           opacities[i], Vec2<T>(sum[kGradMeanX], sum[kGradMeanY]),
                           Vec3<T>(sum[kGradConicA], sum[kGradConicB], sum[kGradConicC]), sum[kGradOpacity],
                           sum[kGradDepth], grad_mean, grad_cov, grad_opacity);
      for (int k = 0; k < 3; ++k) g_means[3 * i + k] = grad_mean[k];
      g_opac[i] = grad_opacity;
      if (in.uses_covariances()) {
        pack_covariance_gradient(grad_cov, out.covariances.data_ptr<T>() + 6 * i);
      } else {
        const T* s = in.scales.data_ptr<T>() + 3 * i;
        const T* q = in.rotations.data_ptr<T>() + 4 * i;
        Vec3<T> grad_scale;
        Vec4<T> grad_quat;
        covariance_from_scale_rotation_vjp(Vec3<T>(s[0], s[1], s[2]), Vec4<T>(q[0], q[1], q[2], q[3]), grad_cov,
                                           grad_scale, grad_quat);
        for (int k = 0; k < 3; ++k) out.scales.data_ptr<T>()[3 * i + k] = grad_scale[k];
        for (int k = 0; k < 4; ++k) out.rotations.data_ptr<T>()[4 * i + k] = grad_quat[k];
      }
    }
  });

  out.background = at::zeros_like(in.background);
  T* g_bg = out.background.data_ptr<T>();
  for (int64_t t = 0; t < n_tiles; ++t)
    for (int64_t c = 0; c < channels; ++c) g_bg[c] += background_partial[t * channels + c];
  return out;
}

}  // namespace

ForwardOutputs forward(const SplatInputs& in, const CameraSpec& camera, const BackendSettings& settings) {
  if (in.means.scalar_type() == at::kDouble) return forward_typed<double>(in, camera, settings);
  return forward_typed<float>(in, camera, settings);
}

InputGradients backward(const SplatInputs& in, const CameraSpec& camera, const BackendSettings& settings,
                        const ForwardOutputs& forward, const OutputGradients& grads) {
  if (in.means.scalar_type() == at::kDouble) return backward_typed<double>(in, camera, settings, forward, grads);
  return backward_typed<float>(in, camera, settings, forward, grads);
}

}  // namespace sfgs::splat::cpu
