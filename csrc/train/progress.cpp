#include "train/progress.h"

#include <cstdio>
#include <fstream>
#include <vector>

#include <c10/util/Exception.h>
#include <unistd.h>

#include "common/atomic_file.h"

namespace sfgs::train {

namespace {
constexpr int kBarWidth = 30;
}

std::string format_duration(double seconds) {
  const int64_t s = int64_t(seconds + 0.5);
  char buffer[32];
  if (s >= 3600)
    std::snprintf(buffer, sizeof(buffer), "%lldh%02lldm", (long long)(s / 3600), (long long)(s % 3600 / 60));
  else if (s >= 60)
    std::snprintf(buffer, sizeof(buffer), "%lldm%02llds", (long long)(s / 60), (long long)(s % 60));
  else
    std::snprintf(buffer, sizeof(buffer), "%llds", (long long)s);
  return buffer;
}

ProgressBar::ProgressBar(int64_t total, bool enabled)
    : total_(std::max<int64_t>(total, 1)),
      enabled_(enabled),
      terminal_(::isatty(2) != 0),
      start_(std::chrono::steady_clock::now()) {}

double ProgressBar::elapsed_seconds() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
}

void ProgressBar::update(int64_t done, double loss, double psnr) {
  if (!enabled_) return;
  const double fraction = double(done) / double(total_);
  const int64_t tenth = int64_t(fraction * 10);
  if (!terminal_ && tenth == last_tenth_) return;
  last_tenth_ = tenth;
  const double elapsed = elapsed_seconds();
  const double eta = done > 0 ? elapsed * double(total_ - done) / double(done) : 0.0;
  const int filled = int(fraction * kBarWidth);
  std::string bar(size_t(filled), '=');
  if (filled < kBarWidth) bar += '>' + std::string(size_t(kBarWidth - filled - 1), ' ');
  std::fprintf(stderr, "%s[%s] %lld/%lld %3.0f%%  loss %.4f  psnr %.2f  elapsed %s  eta %s%s", terminal_ ? "\r" : "",
               bar.c_str(), (long long)done, (long long)total_, 100 * fraction, loss, psnr,
               format_duration(elapsed).c_str(), format_duration(eta).c_str(), terminal_ ? "" : "\n");
  std::fflush(stderr);
}

void ProgressBar::finish() {
  if (enabled_ && terminal_) std::fprintf(stderr, "\n");
}

JsonLinesLog::JsonLinesLog(const std::string& path) : path_(path), out_(path, std::ios::app) {
  TORCH_CHECK(out_.good(), "cannot open log '", path, "' for appending");
}

void JsonLinesLog::write(const nlohmann::json& entry) {
  out_ << entry.dump() << '\n';
  out_.flush();
  TORCH_CHECK(out_.good(), "cannot write to log '", path_, "'");
}

int64_t truncate_log_after(const std::string& path, int64_t iteration) {
  std::ifstream in(path);
  if (!in) return 0;
  std::string kept, line;
  int64_t dropped = 0;
  while (std::getline(in, line)) {
    const nlohmann::json e = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
    const bool keep = e.is_object() && e.contains("iteration") && e["iteration"].is_number_integer() &&
                      e["iteration"].get<int64_t>() <= iteration;
    if (keep)
      kept += line + "\n";
    else
      ++dropped;
  }
  write_file_atomically(path, std::vector<unsigned char>(kept.begin(), kept.end()), true);
  return dropped;
}

}  // namespace sfgs::train
