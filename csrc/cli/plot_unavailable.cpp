// Stands in for plot_opencv.cpp in builds without OpenCV.
#include "cli/plot.h"

namespace sfgs::cli {

bool write_error_curve_plot(const std::vector<train::ErrorCurvePoint>&, const std::string&, bool) { return false; }

}  // namespace sfgs::cli
