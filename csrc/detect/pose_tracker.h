#pragma once
// The body part of MediaPipe Holistic run with LibTorch (docs/prepare.md): a person detector on the letterboxed
// frame (the largest person is followed), then the pose landmark network on a region that follows the person from
// frame to frame; 33 body landmarks and a person mask per frame. Same pre- and post-processing as MediaPipe's pose
// graph (anchors, weighted suppression, alignment regions, heatmap refinement, one-euro smoothing over a video).
#include <optional>
#include <string>

#include <ATen/core/Tensor.h>

#include "detect/one_euro.h"
#include "detect/region.h"
#include "detect/tflite_network.h"

namespace sfgs::detect {

// MediaPipe's pose landmark models: model complexity 0, 1, 2.
enum class PoseModel { kLite, kFull, kHeavy };

struct PoseOptions {
  PoseModel model = PoseModel::kFull;
  double min_detection_score = 0.5;  // a detection below this is no person
  double min_tracking_score = 0.5;   // a landmark pass whose pose flag is not above this loses the person
  bool smooth = true;                // smooth the landmarks over the frames of a video (one-euro filters)
};

struct PoseFrame {
  bool found = false;
  at::Tensor landmarks;  // (33, 5) on the CPU: x, y (image pixels), z (pixels, relative to the hips), visibility,
                         // presence (probabilities)
  at::Tensor mask;       // (H, W) person probability, on the image's device
  Region region;         // what the landmark network saw
  Region next_region;    // where it looks in the next frame (from this frame's auxiliary landmarks)
  double score = 0;      // the pose flag of the landmark pass
  int64_t people = 0;    // persons the detector saw when this frame detected (0: the region was followed)
};

struct PersonDetection {
  Region region;       // the largest person's, for the landmark network
  int64_t people = 0;  // persons detected
};

class PoseTracker {
 public:
  // Models from mediapipe_models_dir() (detect/models.h), on `device`.
  PoseTracker(at::Device device, PoseOptions options = {});
  // The next frame of a video at time `seconds` (increasing), or of images without a time: (H, W, 3) float32 in
  // [0, 1] on the tracker's device. Detects the person when no region is followed; otherwise follows the region the
  // last frame's landmarks gave. Frames with a time have their landmarks smoothed over the frames followed
  // (PoseOptions::smooth).
  PoseFrame track(const at::Tensor& image, std::optional<double> seconds = std::nullopt);
  // Forgets the followed region and its motion: the next frame detects again (a cut, or a new video).
  void reset() {
    followed_.reset();
    forget_motion();
  }

  // The largest person the detector sees in the image, if any: exposed for tests.
  std::optional<PersonDetection> detect(const at::Tensor& image) const;

 private:
  // The landmark pass on `region`; `auxiliary` gets the two landmarks that place the next region (2, 2).
  PoseFrame landmarks_in(const at::Tensor& image, const Region& region, at::Tensor& auxiliary) const;
  void smooth(PoseFrame& frame, at::Tensor& auxiliary, double seconds);
  void forget_motion();

  PoseOptions options_;
  TfliteNetwork detector_, landmarker_;
  at::Tensor anchors_;  // (2254, 2) anchor centres in the detector's unit square
  std::optional<Region> followed_;
  LandmarkSmoother landmark_smoother_, auxiliary_smoother_;
  at::Tensor last_probabilities_;  // the last frame's smoothed visibility and presence (33, 2)
};

}  // namespace sfgs::detect
