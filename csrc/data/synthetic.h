#pragma once
// `sfgs synth`: a synthetic monocular video with exact ground truth. A textured SMPL-X-layout body (the built-in
// procedural body by default, or any model file such as the Anny stand-in) performs motions of the library
// (motions.h), moving body, fingers, jaw and expression, under a key light fixed in the world with self-shadowing,
// while a hand-held-like camera drifts in front of it; each frame is rendered by the CPU triangle rasteriser
// (mesh_renderer.h), never by Gaussians, and written in sfgs's dataset format with the posed meshes and the
// ground truth that per-region evaluation needs (meshes/regions.npy, meshes/observation.npy).
#include <cstdint>
#include <string>
#include <vector>

#include "data/dataset.h"

namespace sfgs::data {

struct SyntheticVideoOptions {
  std::string body_model;  // SMPL-X-layout .npz; empty: the built-in procedural body
  std::string texture;     // albedo PNG for the model's UVs; empty: a generated pattern
  // Training motions, one block of `frames` frames each, in this order; every 10th frame of them (offset 4) is
  // validation. Without test motions every 10th (offset 9) is test too: the interleaved split.
  std::vector<std::string> motions{"sway"};
  // Motions whose blocks, after the training blocks, are all test frames: the novel-motion split.
  std::vector<std::string> test_motions;
  int64_t frames = 60;  // per motion block
  int64_t width = 256;
  int64_t height = 256;
  double frames_per_second = 30.0;
  uint64_t seed = 1;
  bool key_light = true;   // false: a head light at the camera (shading that follows the view, never the pose)
  bool overwrite = false;  // replace files of an existing dataset in the folder
};

// Writes images/, masks/, meshes/ and dataset.json into `folder` (created if needed) and returns the dataset. Each
// motion block is one sequence named after its motion; frame times run on through the whole video (one recording).
// Splits as the options say (the interleaved one is NeuMan's 80/10/10).
Dataset write_synthetic_video(const std::string& folder, const SyntheticVideoOptions& options);

}  // namespace sfgs::data
