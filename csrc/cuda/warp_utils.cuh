#pragma once
// Warp-level building blocks of the CUDA kernels: reductions over a warp's lanes, the transposing reduction of the
// backward blend, and warp-aggregated atomics.
#include <cstdint>

namespace sfgs::splat::cuda_kernels {

constexpr int kWarpSize = 32;
constexpr unsigned kFullWarp = 0xffffffffu;

template <typename T> __device__ __forceinline__ T warp_sum(T v) {
#pragma unroll
  for (int offset = kWarpSize / 2; offset > 0; offset /= 2) v += __shfl_xor_sync(kFullWarp, v, offset);
  return v;
}

template <typename U> __device__ __forceinline__ U warp_min_of(U v) {
#pragma unroll
  for (int offset = kWarpSize / 2; offset > 0; offset /= 2) {
    const U other = __shfl_xor_sync(kFullWarp, v, offset);
    v = other < v ? other : v;
  }
  return v;
}

template <typename U> __device__ __forceinline__ U warp_max_of(U v) {
#pragma unroll
  for (int offset = kWarpSize / 2; offset > 0; offset /= 2) {
    const U other = __shfl_xor_sync(kFullWarp, v, offset);
    v = other > v ? other : v;
  }
  return v;
}

// Values per lane that warp_transpose_sum reduces (a power of two).
constexpr int kReducedValues = 16;

// Lane l ends with the warp's total of v[l / 2]. Each level keeps half of a lane's values and trades the other half
// with the lane `offset` away: 16 shuffles for all 16 values instead of 5 per value.
template <int kHalf, typename T> __device__ __forceinline__ void keep_half(const T* in, T* out, int lane, int offset) {
  const bool upper = (lane & offset) != 0;
#pragma unroll
  for (int i = 0; i < kHalf; ++i) {
    const T send = upper ? in[i] : in[i + kHalf];
    const T keep = upper ? in[i + kHalf] : in[i];
    out[i] = keep + __shfl_xor_sync(kFullWarp, send, offset);
  }
}

template <typename T> __device__ __forceinline__ T warp_transpose_sum(const T (&v)[kReducedValues], int lane) {
  static_assert(kReducedValues == 16 && kWarpSize == 32, "four halving levels, then one plain exchange");
  T eight[8], four[4], two[2], one[1];
  keep_half<8>(v, eight, lane, 16);
  keep_half<4>(eight, four, lane, 8);
  keep_half<2>(four, two, lane, 4);
  keep_half<1>(two, one, lane, 2);
  return one[0] + __shfl_xor_sync(kFullWarp, one[0], 1);
}

// Adds `amount` to counter c of `counters` for every calling lane, one shared atomic per distinct c in the warp;
// returns this lane's start. All lanes of the warp must call it (lanes with c < 0 take part without counting).
__device__ __forceinline__ unsigned warp_aggregated_add(unsigned* counters, int c, unsigned amount) {
  const unsigned peers = __match_any_sync(kFullWarp, c);
  const int lane = threadIdx.x % kWarpSize, leader = __ffs(peers) - 1;
  const unsigned before = __popc(peers & ((1u << lane) - 1u));
  unsigned base = 0;
  if (lane == leader && c >= 0) base = atomicAdd(counters + c, amount * __popc(peers));
  base = __shfl_sync(kFullWarp, base, leader);
  return base + before * amount;
}

}  // namespace sfgs::splat::cuda_kernels
