#include "train/loss_watch.h"

#include <cmath>
#include <sstream>

#include <ATen/ATen.h>

namespace sfgs::train {

void LossWatch::record(int64_t iteration, const LossTerms& terms, const LossTerms& reported) {
  if (names_.empty()) {
    for (const auto& [name, value] : terms) names_.push_back(name);
    checked_ = names_.size();
    for (const auto& [name, value] : reported) names_.push_back(name);
  }
  TORCH_CHECK(terms.size() == checked_ && terms.size() + reported.size() == names_.size(),
              "LossWatch: the loss terms changed between steps");
  std::vector<at::Tensor> values;
  values.reserve(names_.size());
  for (const LossTerms* group : {&terms, &reported})
    for (const auto& [name, value] : *group) values.push_back(value.detach().reshape({}).to(at::kDouble));
  rows_.push_back(at::stack(values));
  iterations_.push_back(iteration);
}

std::map<std::string, double> LossWatch::read() {
  std::map<std::string, double> latest;
  if (rows_.empty()) return latest;
  const at::Tensor rows = at::stack(rows_).cpu();  // the one synchronisation
  const std::vector<int64_t> iterations = std::move(iterations_);
  rows_.clear();
  iterations_.clear();
  const auto* values = rows.data_ptr<double>();
  const size_t k = names_.size();
  for (size_t r = 0; r < iterations.size(); ++r) {
    std::ostringstream bad;
    for (size_t t = 0; t < checked_; ++t)
      if (!std::isfinite(values[r * k + t]))
        bad << (bad.tellp() > 0 ? ", " : "") << "'" << names_[t] << "' = "
            << (std::isnan(values[r * k + t]) ? "nan"
                : values[r * k + t] > 0       ? "inf"
                                              : "-inf");
    if (bad.tellp() > 0)
      throw DivergenceError(iterations[r], "training diverged at iteration " + std::to_string(iterations[r]) +
                                               ": loss " + bad.str() + " is not finite");
  }
  const size_t last = iterations.size() - 1;
  for (size_t t = 0; t < k; ++t) latest[names_[t]] = values[last * k + t];
  return latest;
}

}  // namespace sfgs::train
