#pragma once
// The optimisation behind `sfgs fit` (fit.h), callable on data in memory (the tests fit known poses with it).
#include <ATen/core/Tensor.h>

#include <functional>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <vector>

#include "body/smplx.h"
#include "body/wholebody_keypoints.h"
#include "fit/fit.h"
#include "fit/fit_input.h"

namespace sfgs::fit {

struct FitSettings {
  FitStageLengths iterations;
  at::Tensor known_betas;  // defined: the shape is kept (padded or cut to the fitted length), not fitted
  // Defined: the fit starts from these fits (B frames in camera coordinates, hands relative to the mean hand, e.g.
  // a pose estimator's) instead of the closed-form start, with `initial_betas` (or known_betas, or zeros).
  std::optional<body::SmplxPose> initial_fits;
  at::Tensor initial_betas;
  bool use_masks = true;                             // run the silhouette stage where the input has masks
  int64_t log_every = 0;                             // steps between progress reports; 0: none
  std::function<void(const std::string&)> progress;  // a human-readable line per report
  std::function<void(const nlohmann::json&)> log;    // a JSON object per report and per finished stage
};

struct FitResult {
  body::SmplxPose poses;  // (B, ...) per frame of the input, camera coordinates, hands relative to the mean hand
  at::Tensor betas;       // (K) float32 CPU
  std::vector<FitStageSummary> stages;
  bool silhouette = false;
};

// Fits `model` to the input's keypoints (and masks) on `device`. `keypoint_map` must be built for `model`.
FitResult fit_smplx(const body::SmplxModelData& model, const body::WholeBodyKeypointMap& keypoint_map,
                    const FitInput& input, c10::Device device, const FitSettings& settings);

}  // namespace sfgs::fit
