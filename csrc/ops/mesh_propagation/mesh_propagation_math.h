#pragma once
// The steps of the propagation over a mesh (csrc/ops/mesh_propagation/mesh_propagation.h), written once for the CPU
// backend and the CUDA kernels: a ring point's mean over its neighbours filled before its ring, a smoothing step's
// mean over all its neighbours, and the final blend by trust. No torch in here.
#include <cstdint>
#include <limits>

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

// out (C) := the mean of rows rows[0 .. count) of `from` (N, C); 0 when count is 0. Sums in the rows' order. A
// count outside [0, slots] or a row outside [0, N) (a plan plan() did not make: the CPU op refuses one, the CUDA
// kernels cannot check it without reading the device) gives NaN, and nothing outside the arrays is read.
template <typename T>
SFGS_HD void mean_of_rows(const int32_t* __restrict__ rows, int count, const PropagationArrays<T>& a,
                          const T* __restrict__ from, T* __restrict__ out) {
  const int channels = a.channels;
  const bool bad_count = count < 0 || count > a.slots;
  if (bad_count) count = 0;
  bool bad_row = false;
  const T scale = T(1) / T(count > 0 ? count : 1);
  for (int first = 0; first < channels; first += kChannelsAtOnce) {
    const int width = channels - first < kChannelsAtOnce ? channels - first : kChannelsAtOnce;
    T sum[kChannelsAtOnce] = {};
    for (int k = 0; k < count; k += kRowsAtOnce) {
      const int batch = count - k < kRowsAtOnce ? count - k : kRowsAtOnce;
      int32_t q[kRowsAtOnce];
      for (int j = 0; j < kRowsAtOnce; ++j) {
        q[j] = j < batch ? rows[k + j] : 0;
        if (q[j] < 0 || q[j] >= a.point_count) bad_row = true, q[j] = 0;
      }
      T v[kRowsAtOnce][kChannelsAtOnce];
      for (int j = 0; j < kRowsAtOnce; ++j)
        for (int c = 0; c < kChannelsAtOnce; ++c)
          v[j][c] = j < batch && c < width ? from[int64_t(q[j]) * channels + first + c] : T(0);
      for (int j = 0; j < kRowsAtOnce; ++j)
        for (int c = 0; c < kChannelsAtOnce; ++c) sum[c] += v[j][c];
    }
    const bool bad = bad_count || bad_row;
    for (int c = 0; c < width; ++c) out[first + c] = bad ? std::numeric_limits<T>::quiet_NaN() : sum[c] * scale;
  }
}

// Whether point p is a row of the arrays; a point outside them (a plan plan() did not make) is skipped, not written.
template <typename T> SFGS_HD bool is_point(const PropagationArrays<T>& a, int32_t p) {
  return p >= 0 && p < a.point_count;
}

// Ring point i: its row of `filled` := the mean of its neighbours filled before its ring.
template <typename T> SFGS_HD void fill_ring_point(const PropagationArrays<T>& a, int64_t i) {
  const int32_t p = a.ring_points[i];
  if (!is_point(a, p)) return;
  mean_of_rows(a.ring_sources + i * a.slots, a.ring_source_counts[i], a, a.filled, a.filled + int64_t(p) * a.channels);
}

// Free point i: its row of `to` := the mean of all its neighbours' rows of `from`.
template <typename T> SFGS_HD void smooth_free_point(const PropagationArrays<T>& a, int64_t i, const T* from, T* to) {
  const int32_t p = a.free_points[i];
  if (!is_point(a, p)) return;
  mean_of_rows(a.neighbours + int64_t(p) * a.slots, a.counts[p], a, from, to + int64_t(p) * a.channels);
}

// Element i of (N, C): trust v + (1 - trust) propagated.
template <typename T> SFGS_HD T blend_by_trust(T trust, T value, T propagated) {
  return trust * value + (T(1) - trust) * propagated;
}

}  // namespace sfgs::mesh_propagation
