#pragma once
// Feature planes read at points that never move: the canonical coordinates the avatar samples its triplanes at are
// fixed for its life. torch's grid_sample backward scatters every read's gradient into the planes with atomic adds,
// which collide wherever many points share a texel (the planes' backward was the training step's costliest kernel:
// 3.5 of 23 ms). With the points fixed, the map from texels to the reads of them is made once (PlaneReads), and the
// backward becomes a gather: each texel's gradient the weighted sum of its reads' incoming gradients, with no
// contention (a CPU backend and a CUDA kernel sharing plane_sampling_math.h). The forward stays grid_sample's.
#include <cstdint>

#include <ATen/core/Tensor.h>
#include "ops/plane_sampling/constants.h"

namespace sfgs::plane_sampling {

// planes (P, C, H, W) read at grid (P, N, 2) of (u along W, v along H) in [-1, 1] -> (N, P C), plane-major:
// grid_sample with mode 'bilinear', padding 'border' and align_corners true, differentiated by LibTorch's backward.
at::Tensor sample_planes(const at::Tensor& planes, const at::Tensor& grid);
// The grid of time planes (P, C, T, W) read at positions (P, N) along W at one time (0-dim) along T: (P, N, 2).
at::Tensor time_grid(const at::Tensor& positions, const at::Tensor& time);

// Which texels each point reads, sorted by texel and cut into chunks of at most kPlaneReadChunk reads of one texel
// (a texel many points read is summed by several workers). Made on the grid's device.
struct PlaneReads {
  at::Tensor chunk_rows, chunk_begins, chunk_ends;       // (K) int32
  at::Tensor points;                                     // (E) int32
  at::Tensor weights;                                    // (E) in the grid's dtype
  int64_t planes = 0, height = 0, width = 0, count = 0;  // the planes' P, H, W and the points' N
};

// The bilinear reads torch::nn::functional::grid_sample makes with mode 'bilinear', padding 'border' and
// align_corners true: grid (P, N, 2) of (u along W, v along H) in [-1, 1] (beyond: the border), planes (P, C, H, W).
// A height of 1 gives reads along one line (v plays no part).
PlaneReads plane_reads(const at::Tensor& grid, int64_t height, int64_t width);

// planes (P, C, H, W) read at grid (P, N, 2) -> (N, P C), plane-major: grid_sample's values, with the backward
// above (the planes only: the grid must not require a gradient). `reads` must be plane_reads(grid, H, W). The
// dispatcher op sfgs::sample_fixed_planes (the reads' tensors as its arguments); its backward is the op
// sfgs::plane_reads_gradient, whose CPU kernel refuses reads outside the planes or points and whose CUDA kernel gives
// such a chunk NaN or skips it (plane_sampling_math.h).
at::Tensor sample_fixed_planes(const at::Tensor& planes, const at::Tensor& grid, const PlaneReads& reads);

// Time planes (P, C, T, W) read at fixed positions along W (P, N) and at one time shared by every point (a 0-dim
// tensor of the planes' dtype and device, in [-1, 1] along T: a recorded step reads it on the device) -> (N, P C),
// grid_sample's values. The backward gathers along W with `reads` (plane_reads of the positions with height 1) and
// splits the result between the two time rows around the time, by their bilinear weights. The dispatcher op
// sfgs::sample_fixed_planes_at_time.
at::Tensor sample_fixed_planes_at_time(const at::Tensor& planes, const at::Tensor& positions, const at::Tensor& time,
                                       const PlaneReads& reads);

}  // namespace sfgs::plane_sampling
