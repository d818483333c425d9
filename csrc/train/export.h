#pragma once
// A trained avatar's Gaussians for other viewers, in one frame's pose (or the canonical pose), written atomically:
// * .ply: the standard 3DGS binary little-endian layout (x y z, normals, f_dc_0..2, opacity logit, log scales,
//   rotation quaternion w x y z), which 3DGS viewers and tools read;
// * .splat: the compact layout of lightweight web viewers, 32 bytes a Gaussian (position and linear scales as
//   float32, colour and opacity as 8-bit RGBA, the unit rotation quaternion w x y z as bytes q * 128 + 128), largest
//   and most opaque first, so a viewer that streams the file draws the body's bulk first.
#include <string>

#include <ATen/core/Tensor.h>

#include "data/dataset.h"
#include "model/avatar.h"

namespace sfgs::train {

// The Gaussians as viewers take them, float32 on the CPU.
struct ExportedGaussians {
  at::Tensor means;       // (N, 3)
  at::Tensor log_scales;  // (N, 3) log standard deviations along the axes
  at::Tensor rotations;   // (N, 4) unit quaternions (w, x, y, z) of the axes
  at::Tensor colours;     // (N, 3) in [0, 1] where lit within range (shading may exceed 1; viewers clamp)
  at::Tensor opacities;   // (N) in [0, 1]
};

// Frame `frame` of `dataset` (nullptr and frame < 0: the canonical pose). Every value is checked finite.
ExportedGaussians exported_gaussians(model::Avatar& avatar, const data::Dataset* dataset, int64_t frame);

// By the path's extension, .ply or .splat; anything else is an error naming both.
void export_gaussians(model::Avatar& avatar, const data::Dataset* dataset, int64_t frame, const std::string& path,
                      bool overwrite);

void write_ply(const ExportedGaussians& g, const std::string& path, bool overwrite);
void write_splat(const ExportedGaussians& g, const std::string& path, bool overwrite);

}  // namespace sfgs::train
