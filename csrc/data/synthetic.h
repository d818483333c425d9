#pragma once
// `sfgs synth`: a synthetic monocular video with exact ground truth. A textured SMPL-X-layout body (the built-in
// procedural body by default, or any model file such as the Anny stand-in) performs motions of the library
// (motions.h), moving body, fingers, jaw and expression, under a key light fixed in the world with self-shadowing,
// while a hand-held-like camera drifts in front of it; each frame is rendered by the CPU triangle rasteriser
// (mesh_renderer.h), never by Gaussians, and written in sfgs's dataset format with the posed meshes and the
// ground truth that per-region evaluation needs (meshes/regions.npy, meshes/observation.npy), or in the NeuMan /
// ExAvatar layout. Either way each frame also gets whole-body keypoints as a detector would report them
// (keypoints_whole_body/<frame>.json, synthetic_detections.h), and the written fits may be corrupted the way pose
// estimators err (pose_noise.h) while the images stay exact.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "data/pose_noise.h"
#include "data/synthetic_detections.h"

namespace sfgs::data {

enum class DatasetLayout {
  kSfgs,  // dataset.json, images/%06d.png, masks/, meshes/ (docs/dataset_format.md)
  // images/%05d.png, masks/%d.png, sparse/, train_split.txt, test_split.txt, smplx_optimized/ (the fits, in camera
  // coordinates) and ground_truth/ (the exact fits, same files): what read_neuman and `sfgs fit` read
  kNeuman,
};

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
  DatasetLayout layout = DatasetLayout::kSfgs;
  PoseNoiseLevel pose_noise;     // corruption of the written fits (and betas); none by default
  DetectorNoise keypoint_noise;  // of the keypoint files
  // Called after each frame is written with (frames written, frames in all): a long synthesis reports as it goes.
  std::function<void(int64_t, int64_t)> progress;
};

// Writes the video into `folder` (created if needed) in the chosen layout and returns the dataset as read back.
// Each motion block is one sequence named after its motion (the NeuMan layout has one sequence); frame times run on
// through the whole video (one recording). Splits as the options say (the interleaved one is NeuMan's 80/10/10; the
// NeuMan layout lists train and test frames, the validation frames in neither). With pose noise the sfgs layout keeps
// the exact fits beside the noisy ones (FrameRecord::true_pose, Dataset::true_betas).
Dataset write_synthetic_video(const std::string& folder, const SyntheticVideoOptions& options);

}  // namespace sfgs::data
