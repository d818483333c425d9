#pragma once
// Per-frame whole-body keypoint files in the NeuMan / ExAvatar layout: `keypoints_whole_body/<frame>.json`, a JSON
// list of 133 [x, y, score] triples (COCO-WholeBody order, body/wholebody_keypoints.h; pixels with the image's
// top-left corner at (0, 0)), which ExAvatar's preprocessing writes from DWPose and `sfgs synth` writes from the
// exact posed body. `sfgs fit` reads both the same way.
#include <ATen/core/Tensor.h>

#include <cstdint>
#include <map>
#include <string>

namespace sfgs::data {

inline constexpr const char* kKeypointFolder = "keypoints_whole_body";

// (133, 3) float32 [x, y, score] of one file: nested triples or a flat list of 399 numbers. Errors name the file
// and what was expected: a missing or unparsable file (with a hint when it holds Python's NaN / Infinity), another
// keypoint count, a triple that is not three numbers (naming the keypoint), a non-finite value.
at::Tensor read_wholebody_keypoints(const std::string& path);

// Writes (133, 3) keypoints atomically as nested triples (pixels to 1/100, scores to 1/1000); refuses to replace a
// file unless `overwrite`.
void write_wholebody_keypoints(const std::string& path, const at::Tensor& keypoints, bool overwrite);

// The keypoint files of `folder` (its keypoints_whole_body/), by frame number. Errors: no such folder, no file, a
// .json whose name is not a frame number.
std::map<int64_t, std::string> list_keypoint_files(const std::string& folder);

}  // namespace sfgs::data
