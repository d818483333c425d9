#pragma once
// Internal to `sfgs synth` (synthetic.cpp): the two on-disk layouts a synthetic video is written in. The frames'
// images, masks, meshes and keypoint files are written as they are rendered; these write what indexes them.
#include <ATen/core/Tensor.h>

#include <map>
#include <string>
#include <vector>

#include "data/dataset.h"
#include "data/synthetic.h"

namespace sfgs::data {

// Where frame `index` of a video keeps its files in `layout`.
struct SyntheticFramePaths {
  std::string image, mask, mesh, keypoints;  // mesh empty in the NeuMan layout
};
SyntheticFramePaths synthetic_frame_paths(const std::string& folder, DatasetLayout layout, int64_t index);

// Everything about the rendered frames the index files need. Poses are in world coordinates with absolute hand
// poses (the synthetic layer's flat hand).
struct SyntheticVideo {
  std::vector<std::string> sequences;  // one per motion block
  std::vector<FrameRecord> frames;     // pose = the fits as written (noisy or exact), true_pose = exact when noisy
  std::map<Split, std::vector<int64_t>> splits;
  at::Tensor betas;                              // as written
  at::Tensor true_betas;                         // the exact shape when noisy, else undefined
  at::Tensor rest_pelvis, true_rest_pelvis;      // (B, 3) per frame under the written / exact shape and expression
  at::Tensor hands_mean_left, hands_mean_right;  // (45) the model's mean hand poses
};

// dataset.json (plus meshes/faces, regions and observation written by the caller).
void write_sfgs_layout_index(const std::string& folder, const SyntheticVideo& video, bool overwrite);

// sparse/, the split files, smplx_optimized/ (the written fits) and ground_truth/ (the exact ones), both in each
// frame's camera coordinates with hand poses relative to the model's mean hand, as ExAvatar's fits are.
void write_neuman_layout_index(const std::string& folder, const SyntheticVideo& video, bool overwrite);

}  // namespace sfgs::data
