#pragma once
// An evaluation as JSON (summary and per-frame values), as eval, ablate and demo write it.
#include <string>

#include <nlohmann/json.hpp>

#include "train/evaluate.h"

namespace sfgs::cli {

nlohmann::json evaluation_json(const train::AvatarEvaluation& evaluation);
// One line per motion and per region ("  motion bend  frames 40  PSNR 33.81  SSIM 0.9876  LPIPS 0.0079").
std::string group_lines(const train::AvatarEvaluation& evaluation);

}  // namespace sfgs::cli
