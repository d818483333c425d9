#pragma once
// Catches a diverging run. Every step's loss terms stay on the device, stacked into one small tensor; they are read
// back together when the trainer reads its logged values anyway (or validates, or checkpoints), so watching adds no
// host synchronisation per step. A NaN or Inf names the first iteration and the terms it appeared in.
#include <stdexcept>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

#include "train/losses.h"

namespace sfgs::train {

// Thrown by LossWatch::read when a term was not finite; what() says where and in which terms.
class DivergenceError : public std::runtime_error {
 public:
  DivergenceError(int64_t iteration, const std::string& message) : std::runtime_error(message), iteration_(iteration) {}
  int64_t iteration() const { return iteration_; }

 private:
  int64_t iteration_;
};

class LossWatch {
 public:
  // Keeps this step's terms (the same names every step) without reading them; `reported` values (e.g. the step's
  // PSNR, which is +Inf for a perfect match) are read back alongside but not checked.
  void record(int64_t iteration, const LossTerms& terms, const LossTerms& reported = {});
  // Reads everything recorded since the last read (one device-to-host copy) and returns the latest step's values by
  // name; throws DivergenceError at the first step that had a non-finite term. Empty before any record.
  std::map<std::string, double> read();

 private:
  std::vector<std::string> names_;
  size_t checked_ = 0;  // the first checked_ names are loss terms, the rest reported values
  std::vector<at::Tensor> rows_;
  std::vector<int64_t> iterations_;
};

}  // namespace sfgs::train
