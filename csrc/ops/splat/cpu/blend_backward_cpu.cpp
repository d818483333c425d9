// CPU backward blend: each pixel's blend is replayed front to back (its transmittances re-evaluated, not recovered
// by dividing) and walked back to front; every pair's gradient goes into its intersection's own slot, and the
// slots are summed per Gaussian in a fixed order, so the gradients are bit-identical for any thread count.
#include <array>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "ops/splat/cpu/stages_cpu.h"
#include "ops/splat/constants.h"

namespace sfgs::splat::cpu {
namespace {

// One blended pair remembered while replaying a pixel front to back.
template <typename T> struct ReplayedPair {
  int64_t slot;  // emission slot = gradient slot of this intersection
  PairAlpha<T> pair;
  T transmittance;  // before this pair
};

// What the per-tile pass shares: inputs, forward state and the slots it writes.
template <typename T> struct BackwardPass {
  const SplatScene<T>& scene;
  const TileGrid& grid;
  const TileLists<T>& lists;
  const T* final_transmittance;
  const int32_t* contributors;
  const OutputGradientArrays<T>& grads;
  T* slots;                // (intersections, kProjectedGradWidth + C)
  T* background_partials;  // (tiles, C)
};

// Replays the forward blend of the tile's pixels (same pairs, same products), remembering each pixel's blended
// pairs in replay.
template <typename T>
void replay_tile(const BackwardPass<T>& a, int64_t tile, std::vector<TileEntry<T>>& entries,
                 std::vector<std::vector<ReplayedPair<T>>>& replay) {
  const TileBox box = tile_box(a.grid, tile);
  const auto last_of = [&](int lx, int ly) {
    return a.contributors[int64_t(box.y0 + ly) * a.grid.width + box.x0 + lx];
  };
  int32_t longest = 0;
  for (int ly = 0; ly < box.height; ++ly)
    for (int lx = 0; lx < box.width; ++lx) longest = std::max(longest, last_of(lx, ly));
  const int64_t begin = a.lists.tile_offsets[tile];
  gather_tile(a.grid, tile, a.lists, begin, begin + longest, entries);
  for (auto& r : replay) r.clear();
  std::array<T, kTilePixels> transmittance;
  transmittance.fill(T(1));
  for (size_t k = 0; k < entries.size(); ++k) {
    const TileEntry<T>& e = entries[k];
    for (int ly = e.y0; ly <= std::min(e.y1, box.height - 1); ++ly)
      for (int lx = e.x0; lx <= std::min(e.x1, box.width - 1); ++lx) {
        if (int32_t(k) >= last_of(lx, ly)) continue;
        const int p = ly * kTileSize + lx;
        PairAlpha<T> pair;
        if (!pair_alpha(e.g, T(box.x0 + lx) + T(kPixelCentre), T(box.y0 + ly) + T(kPixelCentre), pair)) continue;
        replay[size_t(p)].push_back(ReplayedPair<T>{e.slot, pair, transmittance[p]});
        transmittance[p] *= T(1) - pair.alpha;
      }
  }
}

// Walks one pixel's replayed pairs back to front, adding each pair's gradient to its slot.
template <typename T>
void pixel_gradients(const BackwardPass<T>& a, int64_t pix, const std::vector<ReplayedPair<T>>& pairs, T* bg_partial) {
  const SplatScene<T>& s = a.scene;
  const int64_t channels = s.channels;
  const int64_t slot_width = kProjectedGradWidth + channels;
  const T* g_colour = a.grads.image + pix * channels;
  const T grad_depth = a.grads.depth_sum[pix], grad_alpha = a.grads.alpha[pix];
  const T final_transmittance = a.final_transmittance[pix];
  for (int64_t c = 0; c < channels; ++c) bg_partial[c] += final_transmittance * g_colour[c];
  T behind_colour = T(0);
  for (int64_t c = 0; c < channels; ++c) behind_colour += final_transmittance * s.background[c] * g_colour[c];
  T behind_depth = T(0);
  for (auto it = pairs.rbegin(); it != pairs.rend(); ++it) {
    const int64_t gi = a.lists.isect_gaussian[it->slot];
    const ProjectedGaussian<T> g = load_projected(a.lists.projected + gi * kProjectedWidth);
    const T* f = s.features + gi * channels;
    T* slot = a.slots + it->slot * slot_width;
    const T weight = it->pair.alpha * it->transmittance;
    T colour_dot = T(0);
    for (int64_t c = 0; c < channels; ++c) {
      slot[kProjectedGradWidth + c] += weight * g_colour[c];
      colour_dot += f[c] * g_colour[c];
    }
    slot[kGradDepth] += weight * grad_depth;
    const T grad_pair_alpha = composite_grad_alpha(it->pair.alpha, it->transmittance, colour_dot, behind_colour,
                                                   g.depth, grad_depth, behind_depth, final_transmittance, grad_alpha);
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

template <typename T> void tile_gradients(const BackwardPass<T>& a, int64_t begin, int64_t end) {
  std::vector<TileEntry<T>> entries;
  std::vector<std::vector<ReplayedPair<T>>> replay(kTilePixels);
  for (int64_t tile = begin; tile < end; ++tile) {
    replay_tile(a, tile, entries, replay);
    const TileBox box = tile_box(a.grid, tile);
    for (int ly = 0; ly < box.height; ++ly)
      for (int lx = 0; lx < box.width; ++lx)
        pixel_gradients(a, int64_t(box.y0 + ly) * a.grid.width + box.x0 + lx, replay[size_t(ly * kTileSize + lx)],
                        a.background_partials + tile * a.scene.channels);
  }
}

// Sums each Gaussian's slots in emission order and turns the sums into its input gradients.
template <typename T>
void gaussian_gradients(const SplatScene<T>& s, const int64_t* gaussian_offsets, const T* slots,
                        const Gradients<T>& out) {
  const int64_t slot_width = kProjectedGradWidth + s.channels;
  at::parallel_for(0, s.count, kGaussiansPerTask, [&](int64_t begin, int64_t end) {
    std::vector<T> sum(static_cast<size_t>(slot_width));
    for (int64_t i = begin; i < end; ++i) {
      if (gaussian_offsets[i] == gaussian_offsets[i + 1]) continue;
      std::fill(sum.begin(), sum.end(), T(0));
      for (int64_t k = gaussian_offsets[i]; k < gaussian_offsets[i + 1]; ++k)
        for (int64_t f = 0; f < slot_width; ++f) sum[size_t(f)] += slots[k * slot_width + f];
      for (int c = 0; c < s.channels; ++c) out.features[i * s.channels + c] = sum[size_t(kProjectedGradWidth + c)];
      write_input_gradients(s, i, sum.data(), out);
    }
  });
}

}  // namespace

template <typename T>
void blend_backward(const SplatScene<T>& s, const TileGrid& grid, const TileLists<T>& lists,
                    const int64_t* gaussian_offsets, int64_t intersections, const T* final_transmittance,
                    const int32_t* contributors, const OutputGradientArrays<T>& grads, const Gradients<T>& out) {
  const int64_t tiles = tile_count(grid);
  std::vector<T> slots(size_t(intersections * (kProjectedGradWidth + s.channels)), T(0));
  std::vector<T> background_partials(size_t(tiles * s.channels), T(0));
  const BackwardPass<T> pass{
      s, grid, lists, final_transmittance, contributors, grads, slots.data(), background_partials.data()};
  at::parallel_for(0, tiles, 1, [&](int64_t begin, int64_t end) { tile_gradients(pass, begin, end); });
  gaussian_gradients(s, gaussian_offsets, slots.data(), out);
  for (int64_t t = 0; t < tiles; ++t)
    for (int c = 0; c < s.channels; ++c) out.background[c] += background_partials[size_t(t * s.channels + c)];
}

#define SFGS_INSTANTIATE(T)                                                                                            \
  template void blend_backward<T>(const SplatScene<T>&, const TileGrid&, const TileLists<T>&, const int64_t*, int64_t, \
                                  const T*, const int32_t*, const OutputGradientArrays<T>&, const Gradients<T>&);
SFGS_INSTANTIATE(float)
SFGS_INSTANTIATE(double)
#undef SFGS_INSTANTIATE

}  // namespace sfgs::splat::cpu
