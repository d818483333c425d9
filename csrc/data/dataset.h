#pragma once
// A monocular video with masks, cameras and per-frame SMPL-X parameters, whatever format it came from. The trainer
// and evaluator see only this. docs/dataset_format.md describes sfgs's own on-disk format; the NeuMan and X-Humans
// readers (neuman.h, xhumans.h) produce the same structure.
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <ATen/core/Tensor.h>

#include "body/smplx_pose.h"
#include "data/image_io.h"
#include "ops/splat/splat.h"

namespace sfgs::data {

// A frame's SMPL-X parameters (body::SmplxPose, float32 on the CPU, every field defined).
using body::SmplxPose;

struct FrameRecord {
  std::string name;
  double time = 0;       // seconds since the start of its sequence
  int64_t sequence = 0;  // index into Dataset::sequences (X-Humans takes; 0 otherwise)
  Camera camera;
  SmplxPose pose;
  // Whether the parameters place the body in the frame's camera coordinates (ExAvatar's NeuMan fits) rather than
  // in world coordinates; render such a frame with an identity world_to_camera.
  bool pose_in_camera_frame = false;
  std::string image_path;
  std::string mask_path;  // training mask; empty if none
  MaskEncoding mask_encoding = MaskEncoding::kWhitePerson;
  std::string eval_mask_path;  // mask of the evaluation protocol; empty = the training mask
  MaskEncoding eval_mask_encoding = MaskEncoding::kWhitePerson;
  std::string mesh_path;  // ground-truth posed vertices (.npy, float32 (V, 3)); empty if none
  // The frame's whole-body keypoint detections (data/keypoint_file.h; pose fitting anchors on them); empty if none.
  std::string keypoints_path;
  // The exact parameters when `pose` was corrupted on purpose (`sfgs synth --pose-noise`), in the same frame; none
  // for every other dataset.
  std::optional<SmplxPose> true_pose;
};

struct Frame {
  at::Tensor image;      // (H, W, 3) float32 in [0, 1], RGB
  at::Tensor mask;       // (H, W) float32 in {0, 1}; all ones when the record has no mask
  at::Tensor eval_mask;  // (H, W) float32, the evaluation protocol's mask
};

enum class Split { kTrain, kVal, kTest };
// "train", "val" or "test": how files, options and messages name a split.
const char* split_name(Split split);
// NeuMan's interleaved 80/10/10 split of a video's frames: every 10th frame (offset 4) is validation, every 10th
// (offset 9) test, the others training.
Split interleaved_split(int64_t frame);

class Dataset {
 public:
  std::string source;  // folder it was read from
  std::string format;  // "sfgs", "neuman" or "xhumans"
  std::vector<FrameRecord> frames;
  std::vector<std::string> sequences;  // names of the sequences (takes); at least one
  std::map<Split, std::vector<int64_t>> splits;
  at::Tensor betas;       // (B) shared shape parameters, float32
  at::Tensor true_betas;  // the exact shape when `betas` was corrupted on purpose; else undefined

  int64_t size() const { return int64_t(frames.size()); }
  const std::vector<int64_t>& split(Split s) const;
  // How many frames of the split have a keypoint file (FrameRecord::keypoints_path).
  int64_t frames_with_keypoints(Split s) const;
  // Reads the frame's image and masks; errors name the file.
  Frame load(int64_t index) const;
  // The frame's time on the avatar's time axis (model/frame_time.h) when the frame replays what training saw: its
  // seconds mapped to [-1, 1] over the span of the training frames (clamped at the ends), for a frame within the span
  // of its own sequence's training frames or past an end by no more than half their largest gap (as near a trained
  // time as a held-out frame between them). None for any other frame (a sequence of new motions, a moment beyond
  // those training saw): the avatar then leaves its time branch out. A dataset without a training split counts
  // every frame as one.
  std::optional<double> replay_time(int64_t index) const;
  // Checks indices, sizes, shapes, finiteness and cameras; called by every reader and by the writer. Errors name the
  // frame and the field.
  void validate() const;
  // A checksum of what training sees (frame names, times, cameras, SMPL-X parameters, splits, betas), as hex: equal
  // for the same data wherever its folder lies, different for other data. A run refuses to resume on another.
  std::string fingerprint() const;
};

// Dataset::replay_time's answer for every frame from one pass over the training split: a caller that asks per step
// (the trainer) builds it once. It copies what it needs: later changes to the dataset do not reach it.
class ReplayClock {
 public:
  explicit ReplayClock(const Dataset& dataset);
  std::optional<double> time_of(const FrameRecord& frame) const;

 private:
  struct Span {
    double first, last;  // its sequence's earliest and latest training times
    double reach;        // how far past either end a frame still replays: half the largest gap between them
  };
  double lo_ = 0, hi_ = 0;         // the span of every training frame: the time axis
  std::map<int64_t, Span> spans_;  // per sequence with training frames
};

// sfgs's own format (docs/dataset_format.md).
Dataset read_sfgs_dataset(const std::string& folder);
// Writes dataset.json into `folder` atomically; images, masks and meshes must already be there (their paths are
// stored relative to the folder). Refuses to replace an existing dataset.json unless `overwrite`.
void write_sfgs_dataset(const Dataset& dataset, const std::string& folder, bool overwrite);

// Reads whichever known format the folder holds (sfgs, NeuMan, X-Humans subject folder).
Dataset read_dataset(const std::string& folder);

}  // namespace sfgs::data
