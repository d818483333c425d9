#pragma once
// An evaluation as JSON (summary and per-frame values), as eval, ablate and demo write it.
#include <nlohmann/json.hpp>

#include "train/evaluate.h"

namespace sfgs::cli {

nlohmann::json evaluation_json(const train::AvatarEvaluation& evaluation);

}  // namespace sfgs::cli
