#pragma once
// The benchmarks' StageRecorder: wall milliseconds of every named stage (common/stage_timer.h), the device
// synchronised at each bracket so that a stage's queued GPU work counts in it. Nested stages count in their own
// row and in the enclosing one's. Synchronising costs the overlap of host and device work: the split explains a
// frame; the frame time itself is measured without the recorder.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <torch/cuda.h>

#include "common/stage_timer.h"

namespace sfgs::bench {

class StageClock : public StageRecorder {
 public:
  explicit StageClock(bool cuda) : cuda_(cuda) {}

  void begin(const char* stage) override {
    sync();
    open_.push_back({stage, std::chrono::steady_clock::now()});
  }
  void end(const char* stage) override {
    sync();
    const auto now = std::chrono::steady_clock::now();
    for (auto it = open_.rbegin(); it != open_.rend(); ++it)
      if (it->name == stage) {
        Row& row = rows_[stage];
        row.ms += std::chrono::duration<double, std::milli>(now - it->start).count();
        ++row.calls;
        if (std::find(order_.begin(), order_.end(), stage) == order_.end()) order_.push_back(stage);
        open_.erase(std::next(it).base());
        return;
      }
  }
  void clear() { rows_.clear(); }
  // Milliseconds per unit (frame or step) of every stage, in first-seen order, and its share of `total`.
  void print(int64_t units, const char* total) const {
    const auto t = rows_.find(total);
    const double total_ms = t == rows_.end() ? 0 : t->second.ms / double(units);
    for (const std::string& name : order_) {
      const Row& row = rows_.at(name);
      const double ms = row.ms / double(units);
      std::printf("    %-52s %9.3f ms %6.1f %%\n", name.c_str(), ms, total_ms > 0 ? 100 * ms / total_ms : 0.0);
    }
  }

 private:
  struct Open {
    std::string name;
    std::chrono::steady_clock::time_point start;
  };
  struct Row {
    double ms = 0;
    int64_t calls = 0;
  };
  void sync() const {
    if (cuda_) torch::cuda::synchronize();
  }
  bool cuda_;
  std::vector<Open> open_;
  std::map<std::string, Row> rows_;
  std::vector<std::string> order_;
};

}  // namespace sfgs::bench
