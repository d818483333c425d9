#pragma once
// How far a fit lies from exact fits: joint and vertex errors in millimetres (fit.h FitAccuracy), with the full
// SMPL-X layer. The exact fits come from an ExAvatar-style folder (what `sfgs synth --layout neuman` writes as
// ground_truth/) or from an sfgs dataset (its exact fits beside noisy ones, else its fits).
#include <ATen/core/Tensor.h>

#include <map>
#include <optional>
#include <string>

#include "body/smplx.h"
#include "fit/fit.h"

namespace sfgs::fit {

// Fits of frames by number: camera coordinates unless world_to_camera is given.
struct ReferenceFits {
  std::string source;
  std::map<int64_t, body::SmplxPose> poses;
  at::Tensor betas;
  bool hands_relative_to_mean = true;             // ExAvatar's and sfgs synth's convention; false: absolute
  std::map<int64_t, at::Tensor> world_to_camera;  // (4, 4) per frame when the poses are in world coordinates
};

// The exact fits for `data`: `truth` (a folder with shape_param.json and smplx_params/) when given, else
// <data>/ground_truth when it exists, else an sfgs dataset's exact fits; nullopt when there are none.
std::optional<ReferenceFits> find_reference_fits(const std::string& data, const std::string& truth);

// Errors of `fitted` (camera coordinates, hands relative to the mean) against `reference` over their common frames.
FitAccuracy measure_accuracy(const body::SmplxModelData& model, const std::map<int64_t, body::SmplxPose>& fitted,
                             const at::Tensor& fitted_betas, const ReferenceFits& reference);

}  // namespace sfgs::fit
