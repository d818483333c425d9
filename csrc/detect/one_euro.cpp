#include "detect/one_euro.h"

#include <cmath>

#include <ATen/ATen.h>

#include "common/math_constants.h"

namespace sfgs::detect {
namespace {

// The rate assumed before two frames have given one (MediaPipe starts at 30 Hz).
constexpr double kInitialFrequency = 30.0;
constexpr double kDerivativeCutoff = 1.0;  // Hz, the speed's own low-pass

}  // namespace

OneEuroFilter::OneEuroFilter(double min_cutoff, double beta, double derivative_cutoff)
    : min_cutoff_(min_cutoff), beta_(beta), derivative_cutoff_(derivative_cutoff), frequency_(kInitialFrequency) {}

double OneEuroFilter::alpha(double cutoff) const {
  const double period = 1.0 / frequency_, tau = 1.0 / (kTwoPi * cutoff);
  return 1.0 / (1.0 + tau / period);
}

double OneEuroFilter::apply(double value, double seconds, double value_scale) {
  if (!started_) {
    started_ = true;
    last_seconds_ = seconds;
    last_raw_ = last_filtered_ = value;
    last_speed_ = 0;
    return value;
  }
  if (seconds <= last_seconds_) return last_filtered_;  // time must advance
  frequency_ = 1.0 / (seconds - last_seconds_);
  last_seconds_ = seconds;
  const double speed = (value - last_raw_) * value_scale * frequency_;
  const double a = alpha(derivative_cutoff_);
  last_speed_ = a * speed + (1 - a) * last_speed_;
  const double b = alpha(min_cutoff_ + beta_ * std::abs(last_speed_));
  last_filtered_ = b * value + (1 - b) * last_filtered_;
  last_raw_ = value;
  return last_filtered_;
}

LandmarkSmoother::LandmarkSmoother(double min_cutoff, double beta) : min_cutoff_(min_cutoff), beta_(beta) {}

at::Tensor LandmarkSmoother::apply(const at::Tensor& points, double seconds, double object_size) {
  const at::Tensor values = points.to(at::kCPU, at::kDouble).contiguous();
  if (int64_t(filters_.size()) != values.numel())
    filters_.assign(size_t(values.numel()), OneEuroFilter(min_cutoff_, beta_, kDerivativeCutoff));
  at::Tensor out = at::empty_like(values);
  const double* v = values.data_ptr<double>();
  double* o = out.data_ptr<double>();
  const double scale = object_size > 0 ? 1.0 / object_size : 1.0;
  for (int64_t k = 0; k < values.numel(); ++k) o[k] = filters_[size_t(k)].apply(v[k], seconds, scale);
  return out.to(points.scalar_type());
}

}  // namespace sfgs::detect
