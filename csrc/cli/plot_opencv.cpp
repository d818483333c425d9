#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>

#include <ATen/ATen.h>
#include <opencv2/imgproc.hpp>

#include "cli/plot.h"
#include "common/constants.h"
#include "data/image_io.h"
#include "data/constants.h"

namespace sfgs::cli {
namespace {

constexpr int kPanelWidth = 480, kPanelHeight = 360, kMargin = 56;
const cv::Scalar kInk(40, 40, 40), kGrid(225, 225, 225), kValColour(200, 110, 30), kTestColour(40, 40, 210);

// A step of 1, 2 or 5 times a power of ten giving about `ticks` intervals over `span`.
double tick_step(double span, int ticks) {
  const double raw = std::max(span, kMinSpan) / ticks, power = std::pow(10.0, std::floor(std::log10(raw)));
  for (const double m : {1.0, 2.0, 5.0})
    if (m * power >= raw) return m * power;
  return 10.0 * power;
}

std::string label(double v) {
  char text[32];
  std::snprintf(text, sizeof(text), std::fabs(v) >= 100 || v == std::floor(v) ? "%.0f" : "%.1f", v);
  return text;
}

// One panel: both PSNR series against x(point).
void draw_panel(cv::Mat& canvas, int left, const std::vector<train::ErrorCurvePoint>& points,
                const std::function<double(const train::ErrorCurvePoint&)>& x, const std::string& x_name, double y_low,
                double y_high) {
  double x_high = 0;
  for (const auto& p : points) x_high = std::max(x_high, x(p));
  x_high = x_high > 0 ? x_high : 1;
  const int x0 = left + kMargin, x1 = left + kPanelWidth - 16, y0 = kPanelHeight - kMargin, y1 = 28;
  const auto px = [&](double v) { return x0 + int(std::lround((x1 - x0) * v / x_high)); };
  const auto py = [&](double v) { return y0 - int(std::lround((y0 - y1) * (v - y_low) / (y_high - y_low))); };
  const double xs = tick_step(x_high, 5), ys = tick_step(y_high - y_low, 6);
  for (double v = 0; v <= x_high + kMinSpan; v += xs) {
    cv::line(canvas, {px(v), y0}, {px(v), y1}, kGrid);
    cv::putText(canvas, label(v), {px(v) - 10, y0 + 18}, cv::FONT_HERSHEY_SIMPLEX, 0.4, kInk, 1, cv::LINE_AA);
  }
  for (double v = std::ceil(y_low / ys) * ys; v <= y_high + kMinSpan; v += ys) {
    cv::line(canvas, {x0, py(v)}, {x1, py(v)}, kGrid);
    cv::putText(canvas, label(v), {x0 - 34, py(v) + 4}, cv::FONT_HERSHEY_SIMPLEX, 0.4, kInk, 1, cv::LINE_AA);
  }
  cv::rectangle(canvas, {x0, y1}, {x1, y0}, kInk);
  cv::putText(canvas, x_name, {(x0 + x1) / 2 - 50, y0 + 40}, cv::FONT_HERSHEY_SIMPLEX, 0.5, kInk, 1, cv::LINE_AA);
  cv::putText(canvas, "masked PSNR (dB)", {left + 6, 18}, cv::FONT_HERSHEY_SIMPLEX, 0.5, kInk, 1, cv::LINE_AA);
  for (const auto& [colour, y] :
       std::vector<std::pair<cv::Scalar, std::function<double(const train::ErrorCurvePoint&)>>>{
           {kValColour, [](const train::ErrorCurvePoint& p) { return p.val_psnr; }},
           {kTestColour, [](const train::ErrorCurvePoint& p) { return p.test_psnr; }}}) {
    std::vector<cv::Point> line;
    for (const auto& p : points)
      if (std::isfinite(y(p)) && std::isfinite(x(p))) line.emplace_back(px(x(p)), py(y(p)));
    if (line.size() > 1) cv::polylines(canvas, line, false, colour, 2, cv::LINE_AA);
    for (const cv::Point& q : line) cv::circle(canvas, q, 3, colour, cv::FILLED, cv::LINE_AA);
  }
}

}  // namespace

bool write_error_curve_plot(const std::vector<train::ErrorCurvePoint>& points, const std::string& png_path,
                            bool overwrite) {
  double low = INFINITY, high = -INFINITY;
  for (const auto& p : points)
    for (const double v : {p.val_psnr, p.test_psnr})
      if (std::isfinite(v)) low = std::min(low, v), high = std::max(high, v);
  if (!std::isfinite(low)) return false;
  low = std::floor(low) - 1, high = std::ceil(high) + 1;
  cv::Mat canvas(kPanelHeight, 2 * kPanelWidth, CV_8UC3, cv::Scalar(255, 255, 255));
  draw_panel(
      canvas, 0, points, [](const train::ErrorCurvePoint& p) { return double(p.iteration); }, "iteration", low, high);
  draw_panel(
      canvas, kPanelWidth, points, [](const train::ErrorCurvePoint& p) { return p.training_seconds; },
      "training seconds", low, high);
  cv::putText(canvas, "val", {2 * kPanelWidth - 130, 18}, cv::FONT_HERSHEY_SIMPLEX, 0.5, kValColour, 2, cv::LINE_AA);
  cv::putText(canvas, "test", {2 * kPanelWidth - 80, 18}, cv::FONT_HERSHEY_SIMPLEX, 0.5, kTestColour, 2, cv::LINE_AA);
  // OpenCV draws BGR; the PNG writer takes RGB floats in [0, 1].
  const at::Tensor bgr = at::from_blob(canvas.data, {canvas.rows, canvas.cols, 3}, at::kByte);
  data::write_png(png_path, bgr.flip({2}).to(at::kFloat).div(kEightBitMax), overwrite);
  return true;
}

}  // namespace sfgs::cli
