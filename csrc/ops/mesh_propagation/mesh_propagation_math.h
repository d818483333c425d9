#pragma once
// The steps of the propagation over a mesh (csrc/ops/mesh_propagation/mesh_propagation.h), written once for the CPU
// backend and the CUDA kernels: a ring point's mean over its neighbours filled before its ring, a smoothing step's
// mean over all its neighbours, and the final blend by trust. No torch in here.
#include <cstdint>

#include "common/host_device.h"

namespace sfgs::mesh_propagation {

// The mesh, its rings and the buffers, as the backends take them. A point's neighbours are the first counts[p] of
// its K slots; ring point i (of all rings, ring after ring) is ring_points[i], and the first ring_source_counts[i] of
// its K ring_sources slots are its neighbours filled before its ring (the planning host found them).
template <typename T> struct PropagationArrays {
  const int32_t* neighbours;          // (N, K)
  const int32_t* counts;              // (N)
  const int32_t* ring_points;         // (M)
  const int32_t* ring_sources;        // (M, K)
  const int32_t* ring_source_counts;  // (M)
  const int32_t* free_points;         // the points that are not trusted (the smoothing moves them alone)
  int64_t point_count, free_count;
  int slots;        // K
  int channels;     // C of the values
  const T* values;  // (N, C)
  const T* trust;   // (N) in [0, 1]
  T* filled;        // (N, C): the values, then the rings' means, then the smoothing's first buffer
  T* scratch;       // (N, C): the smoothing's second buffer
  T* out;           // (N, C)
};

// Channels summed at once, and rows read at once: a thread issues the loads of kRowsAtOnce neighbours' values before
// it adds them, so a point waits on a few rounds of memory latency, not one per neighbour. A ring holds few points,
// so that latency is its kernel's whole length.
inline constexpr int kChannelsAtOnce = 4;
inline constexpr int kRowsAtOnce = 8;

// out (C) := the mean of rows rows[0 .. count) of `from` (N, C); 0 when count is 0. Sums in the rows' order.
template <typename T>
SFGS_HD void mean_of_rows(const int32_t* __restrict__ rows, int count, int channels, const T* __restrict__ from,
                          T* __restrict__ out) {
  const T scale = T(1) / T(count > 0 ? count : 1);
  for (int first = 0; first < channels; first += kChannelsAtOnce) {
    const int width = channels - first < kChannelsAtOnce ? channels - first : kChannelsAtOnce;
    T sum[kChannelsAtOnce] = {};
    for (int k = 0; k < count; k += kRowsAtOnce) {
      const int batch = count - k < kRowsAtOnce ? count - k : kRowsAtOnce;
      int32_t q[kRowsAtOnce];
      for (int j = 0; j < kRowsAtOnce; ++j) q[j] = j < batch ? rows[k + j] : 0;
      T v[kRowsAtOnce][kChannelsAtOnce];
      for (int j = 0; j < kRowsAtOnce; ++j)
        for (int c = 0; c < kChannelsAtOnce; ++c)
          v[j][c] = j < batch && c < width ? from[int64_t(q[j]) * channels + first + c] : T(0);
      for (int j = 0; j < kRowsAtOnce; ++j)
        for (int c = 0; c < kChannelsAtOnce; ++c) sum[c] += v[j][c];
    }
    for (int c = 0; c < width; ++c) out[first + c] = sum[c] * scale;
  }
}

// Ring point i: its row of `filled` := the mean of its neighbours filled before its ring.
template <typename T> SFGS_HD void fill_ring_point(const PropagationArrays<T>& a, int64_t i) {
  mean_of_rows(a.ring_sources + i * a.slots, a.ring_source_counts[i], a.channels, a.filled,
               a.filled + int64_t(a.ring_points[i]) * a.channels);
}

// Free point i: its row of `to` := the mean of all its neighbours' rows of `from`.
template <typename T> SFGS_HD void smooth_free_point(const PropagationArrays<T>& a, int64_t i, const T* from, T* to) {
  const int32_t p = a.free_points[i];
  mean_of_rows(a.neighbours + int64_t(p) * a.slots, a.counts[p], a.channels, from, to + int64_t(p) * a.channels);
}

// Element i of (N, C): trust v + (1 - trust) propagated.
template <typename T> SFGS_HD T blend_by_trust(T trust, T value, T propagated) {
  return trust * value + (T(1) - trust) * propagated;
}

}  // namespace sfgs::mesh_propagation
