// CPU forward blend: tile by tile, Gaussian by Gaussian over only the pixels each can reach. Per pixel this is
// exactly the front-to-back loop over the tile's list (same pairs, same order, same arithmetic), without visiting
// pairs that must be skipped.
#include <array>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "ops/splat/cpu/stages_cpu.h"
#include "ops/splat/constants.h"

namespace sfgs::splat::cpu {
namespace {

// One tile's running composite, reused from tile to tile by a task.
template <typename T> struct TileState {
  std::vector<TileEntry<T>> entries;
  std::vector<T> colour;  // (kTilePixels, C)
  std::array<T, kTilePixels> transmittance, depth;
  std::array<int32_t, kTilePixels> last;
  std::array<bool, kTilePixels> done;

  explicit TileState(int channels) : colour(size_t(kTilePixels * channels)) {}
  void reset() {
    std::fill(colour.begin(), colour.end(), T(0));
    transmittance.fill(T(1));
    depth.fill(T(0));
    last.fill(0);
    done.fill(false);
  }
};

// Blends the tile's list front to back into st; stops once every pixel of the tile is done.
template <typename T>
void composite_tile(const SplatScene<T>& s, const TileLists<T>& lists, const TileBox& box, TileState<T>& st) {
  const int64_t channels = s.channels;
  int remaining = box.width * box.height;
  for (size_t k = 0; k < st.entries.size() && remaining > 0; ++k) {
    const TileEntry<T>& e = st.entries[k];
    const T* f = s.features + lists.isect_gaussian[e.slot] * channels;
    for (int ly = e.y0; ly <= std::min(e.y1, box.height - 1); ++ly)
      for (int lx = e.x0; lx <= std::min(e.x1, box.width - 1); ++lx) {
        const int p = ly * kTileSize + lx;
        if (st.done[p]) continue;
        PairAlpha<T> pair;
        if (!pair_alpha(e.g, T(box.x0 + lx) + T(kPixelCentre), T(box.y0 + ly) + T(kPixelCentre), pair)) continue;
        const T next = st.transmittance[p] * (T(1) - pair.alpha);
        if (next < T(kMinTransmittance)) {
          st.done[p] = true;
          --remaining;
          continue;
        }
        const T weight = pair.alpha * st.transmittance[p];
        T* c = st.colour.data() + p * channels;
        for (int64_t ch = 0; ch < channels; ++ch) c[ch] += weight * f[ch];
        st.depth[p] += weight * e.g.depth;
        st.transmittance[p] = next;
        st.last[p] = int32_t(k + 1);
      }
  }
}

// Writes the tile's pixels of every output: the composite plus what the background adds.
template <typename T>
void write_tile(const SplatScene<T>& s, const TileGrid& grid, const TileBox& box, const TileState<T>& st,
                BlendOutputs& out) {
  const int64_t channels = s.channels;
  T* image = out.image.data_ptr<T>();
  T* alpha = out.alpha.data_ptr<T>();
  T* depth = out.depth.data_ptr<T>();
  T* final_t = out.final_transmittance.data_ptr<T>();
  int32_t* contributors = out.contributors.data_ptr<int32_t>();
  for (int ly = 0; ly < box.height; ++ly)
    for (int lx = 0; lx < box.width; ++lx) {
      const int p = ly * kTileSize + lx;
      const int64_t pix = int64_t(box.y0 + ly) * grid.width + (box.x0 + lx);
      for (int64_t ch = 0; ch < channels; ++ch)
        image[pix * channels + ch] = st.colour[size_t(p * channels + ch)] + st.transmittance[p] * s.background[ch];
      alpha[pix] = T(1) - st.transmittance[p];
      depth[pix] = expected_depth_of(st.depth[p], T(1) - st.transmittance[p]);
      final_t[pix] = st.transmittance[p];
      contributors[pix] = st.last[p];
    }
}

}  // namespace

template <typename T>
BlendOutputs blend_forward(const SplatScene<T>& s, const TileGrid& grid, const TileLists<T>& lists) {
  const int64_t h = grid.height, w = grid.width;
  const auto real = at::TensorOptions().dtype(c10::CppTypeToScalarType<T>::value);
  BlendOutputs out;
  out.image = at::empty({h, w, int64_t(s.channels)}, real);
  out.alpha = at::empty({h, w}, real);
  out.depth = at::empty({h, w}, real);
  out.final_transmittance = at::empty({h, w}, real);
  out.contributors = at::empty({h, w}, real.dtype(at::kInt));
  at::parallel_for(0, tile_count(grid), 1, [&](int64_t begin, int64_t end) {
    TileState<T> st(s.channels);
    for (int64_t tile = begin; tile < end; ++tile) {
      const TileBox box = tile_box(grid, tile);
      gather_tile(grid, tile, lists, lists.tile_offsets[tile], lists.tile_offsets[tile + 1], st.entries);
      st.reset();
      composite_tile(s, lists, box, st);
      write_tile(s, grid, box, st, out);
    }
  });
  return out;
}

template BlendOutputs blend_forward<float>(const SplatScene<float>&, const TileGrid&, const TileLists<float>&);
template BlendOutputs blend_forward<double>(const SplatScene<double>&, const TileGrid&, const TileLists<double>&);

}  // namespace sfgs::splat::cpu
