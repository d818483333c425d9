#pragma once
// Landmarks smoothed over a video's frames as MediaPipe smooths its pose landmarks: a one-euro filter per value (a
// low-pass whose cut-off rises with the value's speed, so slow motion loses its jitter and fast motion keeps its lag
// small), the speed measured relative to the person's size in the image.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

namespace sfgs::detect {

class OneEuroFilter {
 public:
  // Cut-offs in Hz; `beta` raises the cut-off by this much per unit of speed (scaled values per second).
  OneEuroFilter(double min_cutoff, double beta, double derivative_cutoff);
  // The filtered value at time `seconds` (increasing; the first call returns the value); `value_scale` turns the
  // value's change into the unit the speed is measured in.
  double apply(double value, double seconds, double value_scale);

 private:
  double alpha(double cutoff) const;

  double min_cutoff_, beta_, derivative_cutoff_;
  double frequency_;
  double last_seconds_ = 0;
  bool started_ = false;
  double last_raw_ = 0, last_filtered_ = 0, last_speed_ = 0;
};

class LandmarkSmoother {
 public:
  LandmarkSmoother(double min_cutoff, double beta);
  // Points (K, C) on the CPU, every value filtered on its own; `object_size` in the points' unit (the person's size)
  // scales their speeds. A different K starts afresh.
  at::Tensor apply(const at::Tensor& points, double seconds, double object_size);
  void reset() { filters_.clear(); }

 private:
  double min_cutoff_, beta_;
  std::vector<OneEuroFilter> filters_;
};

}  // namespace sfgs::detect
