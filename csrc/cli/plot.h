#pragma once
// The run-time-versus-error plot: masked PSNR against training iterations and against training seconds, drawn with
// OpenCV when the build has it (without it only the CSV is written).
#include <string>
#include <vector>

#include "train/trainer.h"

namespace sfgs::cli {

// Writes the PNG atomically; false when this build cannot draw it or there is nothing to draw.
bool write_error_curve_plot(const std::vector<train::ErrorCurvePoint>& points, const std::string& png_path,
                            bool overwrite);

}  // namespace sfgs::cli
