#pragma once
// Feature planes sampled bilinearly at points whose coordinates lie in [-1, 1]: a triplane (XY, XZ, YZ) and the
// time planes (XT, YT, ZT) that, with a triplane of their own, make a hexplane. Sampling uses
// align_corners = true everywhere: -1 and +1 are the centres of the first and last texels, so the bounding box
// the coordinates were normalised from maps exactly onto the planes, and border padding never comes into play
// for points inside it.
#include <cstdint>
#include <functional>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "ops/plane_sampling/plane_sampling.h"

namespace sfgs::model {

// The plane reads (plane_sampling.h) of the coordinates last sampled with a gradient, made again only when other
// coordinates come (the avatar's are fixed). The coordinates are held, so their memory cannot come back as other
// values, and their data and version are compared.
class FixedReadsCache {
 public:
  const plane_sampling::PlaneReads& reads(const at::Tensor& coordinates,
                                          const std::function<plane_sampling::PlaneReads()>& make);

 private:
  plane_sampling::PlaneReads reads_;
  at::Tensor coordinates_;
  const void* data_ = nullptr;
  int64_t version_ = -1;
};

// Three (C, R, R) planes; a point (x, y, z) reads XY at (x, y), XZ at (x, z), YZ at (y, z).
class TriplaneImpl : public torch::nn::Module {
 public:
  TriplaneImpl(int64_t channels, int64_t resolution);
  // (N, 3) in [-1, 1] -> (N, 3 C): the XY, XZ and YZ features, concatenated. With a gradient, the backward is
  // plane_sampling.h's gather over the reads of these coordinates, made at the first call and kept while the same
  // coordinates come (the avatar's are fixed).
  at::Tensor sample(const at::Tensor& coordinates) const;
  int64_t width() const { return 3 * planes_.size(1); }

 private:
  at::Tensor planes_;  // (3, C, R, R), rows along the second coordinate
  mutable FixedReadsCache reads_;
};
TORCH_MODULE(Triplane);

// Three (C, T, R) planes; a point (x, y, z) at time t reads XT at (x, t), YT at (y, t), ZT at (z, t).
class TimePlanesImpl : public torch::nn::Module {
 public:
  TimePlanesImpl(int64_t channels, int64_t resolution, int64_t time_resolution);
  // (N, 3) in [-1, 1] and t in [-1, 1] -> (N, 3 C): the XT, YT and ZT features, concatenated. The time is a
  // 0-dim tensor on the planes' device (read there, so a recorded CUDA graph takes each replay's time). With a
  // gradient, the backward is plane_sampling.h's gather along the coordinates (kept as the triplane keeps its reads).
  at::Tensor sample(const at::Tensor& coordinates, const at::Tensor& time) const;
  int64_t width() const { return 3 * planes_.size(1); }

 private:
  at::Tensor planes_;  // (3, C, T, R), rows along time
  mutable FixedReadsCache reads_;
};
TORCH_MODULE(TimePlanes);

}  // namespace sfgs::model
