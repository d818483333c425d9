#pragma once
// `sfgs synth`: a synthetic monocular video with exact ground truth. A textured SMPL-X-layout body (the built-in
// procedural body by default, or any model file such as the Anny stand-in) moves its body, fingers, jaw and
// expression while a hand-held-like camera drifts around it; each frame is rendered by the CPU triangle rasteriser
// (mesh_renderer.h), never by Gaussians, and written in sfgs's dataset format with the posed meshes.
#include <cstdint>
#include <string>

#include "data/dataset.h"

namespace sfgs::data {

struct SyntheticVideoOptions {
  std::string body_model;  // SMPL-X-layout .npz; empty: the built-in procedural body
  std::string texture;     // albedo PNG for the model's UVs; empty: a generated pattern
  int64_t frames = 60;
  int64_t width = 256;
  int64_t height = 256;
  double frames_per_second = 30.0;
  uint64_t seed = 1;
  bool overwrite = false;  // replace files of an existing dataset in the folder
};

// Writes images/, masks/, meshes/ and dataset.json into `folder` (created if needed) and returns the dataset.
// Every 10th frame (offset 4) is validation and every 10th (offset 9) test, the rest training: NeuMan's 80/10/10.
Dataset write_synthetic_video(const std::string& folder, const SyntheticVideoOptions& options);

// The motion alone: SMPL-X parameters of frame `index` (time = index / fps) for a model with `expression_count`
// expression coefficients.
SmplxPose synthetic_pose(int64_t index, double frames_per_second, int64_t expression_count);

}  // namespace sfgs::data
