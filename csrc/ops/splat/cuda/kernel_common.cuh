#pragma once
// What the CUDA stage files share: launch geometry, the layout constants several stages depend on, scratch
// allocation, error checks, stage brackets for the benchmarks' observer, and the tile-rectangle helpers.
#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "ops/splat/cuda/diagnostics.h"
#include "ops/splat/cuda/rasterize_kernels.h"
#include "cuda/warp_utils.cuh"
#include "ops/splat/constants.h"

namespace sfgs::splat::cuda_kernels {

constexpr int kBlendThreads = kTileSize * kTileSize;  // one thread per pixel of a tile
constexpr int kBlendWarps = kBlendThreads / kWarpSize;
constexpr int kLinearThreads = 256;
// Feature channels handled per blend launch; wider features are blended in chunks of kMaxChunkChannels.
constexpr int kMaxChunkChannels = 4;
// Tile rectangles of at most this many tiles keep their touched tiles as a bit mask, so that emission reads the
// tile test's results instead of evaluating it again.
constexpr int kMaskedRectTiles = 64;
// Each tile's intersections are counted and emitted through kTileBuckets counters (Gaussian i uses counter
// i % kTileBuckets, its lane), so that a tile's atomics spread over as many addresses; the tile's run is the
// concatenation of its buckets.
constexpr int kTileBuckets = kWarpSize;
static_assert(kBlendThreads % kWarpSize == 0, "a tile must be whole warps");

// The state behind diagnostics.h (diagnostics.cu).
StageObserver* stage_observer();
Binning requested_binning();
void record_binning(Binning taken);
TileOrder tile_order();
int64_t blend_segment_length();
double blend_cut_share();
void record_blend_path(BlendPath taken);

inline void check_cuda(cudaError_t status, const char* what) {
  if (status != cudaSuccess)
    throw std::runtime_error(std::string("sfgs CUDA backend: ") + what + " failed: " + cudaGetErrorString(status));
}

// Brackets one pipeline stage for an installed StageObserver.
class Stage {
 public:
  Stage(const char* name, cudaStream_t stream) : name_(name), stream_(stream) {
    if (stage_observer() != nullptr) stage_observer()->begin(name_, stream_);
  }
  ~Stage() {
    if (stage_observer() != nullptr) stage_observer()->end(name_, stream_);
  }
  Stage(const Stage&) = delete;
  Stage& operator=(const Stage&) = delete;

 private:
  const char* name_;
  cudaStream_t stream_;
};

template <typename U> U* allocate(const ScratchAllocator& scratch, int64_t count) {
  // A zero-byte request may return null, which CUB reads as "tell me the size": never ask for nothing.
  return static_cast<U*>(scratch(std::max<std::size_t>(1, std::size_t(count) * sizeof(U))));
}

inline unsigned blocks_for(int64_t count, int threads) {
  const int64_t blocks = (count + threads - 1) / threads;
  if (blocks > int64_t(INT32_MAX)) throw std::runtime_error("sfgs CUDA backend: launch of more than 2^31 - 1 blocks");
  return unsigned(blocks);
}

template <typename U> __host__ __device__ U smaller(U a, U b) { return a < b ? a : b; }

template <typename T> TileGrid grid_of(const SplatScene<T>& s) { return make_grid(s.camera.width, s.camera.height); }

__device__ inline bool rect_has_tiles(const TileRect& r) { return r.x0 <= r.x1 && r.y0 <= r.y1; }

__device__ inline int64_t rect_tiles(const TileRect& r) { return int64_t(r.x1 - r.x0 + 1) * (r.y1 - r.y0 + 1); }

// Calls launch(std::integral_constant<int, K>, first channel, channel count) once per chunk of the features.
template <typename Launch> void for_each_channel_chunk(int channels, Launch&& launch) {
  switch (channels) {
    case 1:
      launch(std::integral_constant<int, 1>{}, 0, 1);
      return;
    case 2:
      launch(std::integral_constant<int, 2>{}, 0, 2);
      return;
    case 3:
      launch(std::integral_constant<int, 3>{}, 0, 3);
      return;
    default:
      for (int begin = 0; begin < channels; begin += kMaxChunkChannels)
        launch(std::integral_constant<int, kMaxChunkChannels>{}, begin, std::min(kMaxChunkChannels, channels - begin));
  }
}

}  // namespace sfgs::splat::cuda_kernels
