#pragma once
// How long jobs report: a progress bar with ETA, loss and PSNR on stderr, and machine-readable JSON lines.
#include <chrono>
#include <cstdint>
#include <fstream>
#include <string>

#include <nlohmann/json.hpp>

namespace sfgs::train {

class ProgressBar {
 public:
  // On a terminal the bar redraws in place; otherwise it prints a line at every tenth of the run.
  ProgressBar(int64_t total, bool enabled);
  void update(int64_t done, double loss, double psnr);
  void finish();
  double elapsed_seconds() const;

 private:
  int64_t total_;
  bool enabled_, terminal_;
  int64_t last_tenth_ = -1;
  std::chrono::steady_clock::time_point start_;
};

// Appends one JSON object per line and flushes it, so a crash loses nothing already logged.
class JsonLinesLog {
 public:
  explicit JsonLinesLog(const std::string& path);
  void write(const nlohmann::json& entry);

 private:
  std::string path_;
  std::ofstream out_;
};

// Rewrites the log at `path` (atomically) keeping only the entries of iterations <= `iteration` and dropping lines that
// do not parse (a process killed mid-write leaves half a line). Returns how many lines were dropped; 0 when there
// is no log.
int64_t truncate_log_after(const std::string& path, int64_t iteration);

// "1h02m", "3m12s", "45s".
std::string format_duration(double seconds);

}  // namespace sfgs::train
