// The run-time-versus-error curve: every validation in a run's log as CSV.
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common/atomic_file.h"
#include "train/trainer.h"

namespace sfgs::train {

std::vector<ErrorCurvePoint> write_error_curve_csv(const RunFolder& run, const std::string& csv_path) {
  std::ifstream in(run.log_file());
  TORCH_CHECK(in, "cannot read the training log '", run.log_file(), "'");
  std::map<int64_t, ErrorCurvePoint> rows;
  std::string line;
  const auto number = [](const nlohmann::json& e, const char* key) {
    return e.contains(key) && e[key].is_number() ? e[key].get<double>() : std::nan("");
  };
  while (std::getline(in, line)) {
    const nlohmann::json e = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
    if (!e.is_object() || e.value("event", "") != "validation" || !e.contains("iteration")) continue;
    const int64_t iteration = e["iteration"].get<int64_t>();
    rows[iteration] = {iteration, number(e, "training_seconds"), number(e, "val_psnr"), number(e, "test_psnr")};
  }
  std::ostringstream csv;
  csv << "iteration,training_seconds,val_psnr,test_psnr\n";
  const auto cell = [](double v) { return std::isnan(v) ? std::string() : std::to_string(v); };
  std::vector<ErrorCurvePoint> points;
  for (const auto& [iteration, p] : rows) {
    csv << iteration << ',' << cell(p.training_seconds) << ',' << cell(p.val_psnr) << ',' << cell(p.test_psnr) << '\n';
    points.push_back(p);
  }
  const std::string text = csv.str();
  write_file_atomically(csv_path, std::vector<unsigned char>(text.begin(), text.end()), true);
  return points;
}

}  // namespace sfgs::train
