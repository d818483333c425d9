#include "detect/pose_tracker.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <ATen/ATen.h>

#include "common/math_constants.h"
#include "common/tensor_description.h"
#include "detect/models.h"
#include "detect/ssd.h"

namespace sfgs::detect {
namespace {

// The detector (pose_detection.tflite): a 224 x 224 input in [-1, 1]; per anchor a box and four keypoints (layers
// of one stride merged: two anchors a cell at strides 8 and 16, six at 32).
const SsdLayout kDetectorLayout{224, {8, 16, 32}, {2, 2, 6}, 4};
// The landmark network: 256 x 256 in [0, 1]; 39 landmarks of 5 values (33 of the body, 2 that place the next
// frame's region, 4 unused); heatmaps of 64 x 64 refine them.
constexpr int64_t kLandmarkSize = 256;
constexpr int64_t kLandmarks = 39, kBodyLandmarks = 33, kLandmarkValues = 5;
constexpr int64_t kHeatmapSize = 64, kHeatmapWindow = 7;
constexpr double kMinHeatmapConfidence = 0.5;  // a landmark is refined where its window's peak reaches this
// The body's region: from the hips' centre to the point that gives its scale, upright, 1.25 times as large.
constexpr int kCentreKeypoint = 0, kScaleKeypoint = 1;
constexpr int kNextCentreLandmark = 33, kNextScaleLandmark = 34;
constexpr double kRegionAngle = kPi / 2, kRegionScale = 1.25;
// Smoothing over a video (MediaPipe's pose landmark filtering): one-euro cut-offs (Hz) and speed gains of the body's
// landmarks and of the two that place the next region, and the low-pass weight of visibility and presence.
constexpr double kLandmarkMinCutoff = 0.05, kLandmarkBeta = 80;
constexpr double kAuxiliaryMinCutoff = 0.01, kAuxiliaryBeta = 10;
constexpr double kProbabilitySmoothing = 0.1;

const char* landmark_file(PoseModel model) {
  switch (model) {
    case PoseModel::kLite:
      return "pose_landmark_lite.tflite";
    case PoseModel::kFull:
      return "pose_landmark_full.tflite";
    case PoseModel::kHeavy:
      return "pose_landmark_heavy.tflite";
  }
  return "pose_landmark_full.tflite";
}

}  // namespace

PoseTracker::PoseTracker(at::Device device, PoseOptions options)
    : options_(options),
      detector_(TfliteNetwork::load(mediapipe_model("pose_detection.tflite"), device)),
      landmarker_(TfliteNetwork::load(mediapipe_model(landmark_file(options.model)), device)),
      anchors_(ssd_anchors(kDetectorLayout)),
      landmark_smoother_(kLandmarkMinCutoff, kLandmarkBeta),
      auxiliary_smoother_(kAuxiliaryMinCutoff, kAuxiliaryBeta) {}

void PoseTracker::forget_motion() {
  landmark_smoother_.reset();
  auxiliary_smoother_.reset();
  last_probabilities_ = at::Tensor();
}

std::optional<PersonDetection> PoseTracker::detect(const at::Tensor& image) const {
  const Region frame = letterbox(image.size(1), image.size(0));
  const std::vector<at::Tensor> out =
      detector_.run({crop(image, frame, kDetectorLayout.input, -1.0, 1.0, Border::kZero)});
  const std::vector<std::vector<double>> people =
      detections(out[0], out[1], anchors_, kDetectorLayout, options_.min_detection_score);
  if (people.empty()) return std::nullopt;
  // The largest person is the one the video is of: its size is the distance from the hips' centre to the scale
  // point (the detector's box is the face's).
  const auto size = [](const std::vector<double>& d) {
    return std::hypot(d[size_t(4 + 2 * kScaleKeypoint)] - d[size_t(4 + 2 * kCentreKeypoint)],
                      d[size_t(5 + 2 * kScaleKeypoint)] - d[size_t(5 + 2 * kCentreKeypoint)]);
  };
  const auto largest =
      std::max_element(people.begin(), people.end(), [&](const auto& a, const auto& b) { return size(a) < size(b); });
  const std::vector<double>& d = *largest;
  const auto keypoint = [&](int k) { return frame.to_image(d[size_t(4 + 2 * k)], d[size_t(5 + 2 * k)]); };
  const auto a = keypoint(kCentreKeypoint), b = keypoint(kScaleKeypoint);
  return PersonDetection{alignment_region(a[0], a[1], b[0], b[1], kRegionAngle).scaled(kRegionScale, true),
                         int64_t(people.size())};
}

PoseFrame PoseTracker::landmarks_in(const at::Tensor& image, const Region& region, at::Tensor& auxiliary) const {
  const std::vector<at::Tensor> out = landmarker_.run({crop(image, region, kLandmarkSize, 0.0, 1.0, Border::kZero)});
  PoseFrame frame;
  frame.region = region;
  frame.score = out[1].item<double>();
  if (!(frame.score > options_.min_tracking_score)) return frame;
  at::Tensor values = out[0].view({kLandmarks, kLandmarkValues}).cpu().clone();
  at::Tensor unit = values.slice(1, 0, 2) / double(kLandmarkSize);
  // Heatmap refinement: the score-weighted mean of the 7 x 7 heatmap cells around each landmark, where they are sure.
  const at::Tensor heat = at::sigmoid(out[3].view({kHeatmapSize, kHeatmapSize, kLandmarks})).cpu().contiguous();
  const auto* h = heat.data_ptr<float>();
  auto* u = unit.data_ptr<float>();
  for (int64_t l = 0; l < kLandmarks; ++l) {
    const int64_t col = int64_t(u[2 * l] * kHeatmapSize), row = int64_t(u[2 * l + 1] * kHeatmapSize);
    const int64_t reach = (kHeatmapWindow - 1) / 2;
    double sum = 0, x = 0, y = 0, peak = 0;
    for (int64_t r = std::max<int64_t>(0, row - reach); r < std::min(kHeatmapSize, row + reach + 1); ++r)
      for (int64_t c = std::max<int64_t>(0, col - reach); c < std::min(kHeatmapSize, col + reach + 1); ++c) {
        const double w = h[(r * kHeatmapSize + c) * kLandmarks + l];
        sum += w;
        x += w * double(c);
        y += w * double(r);
        peak = std::max(peak, w);
      }
    if (peak >= kMinHeatmapConfidence && sum > 0) {
      u[2 * l] = float(x / sum / kHeatmapSize);
      u[2 * l + 1] = float(y / sum / kHeatmapSize);
    }
  }
  const at::Tensor pixels = points_to_image(unit.to(at::kDouble), region).to(at::kFloat);
  const at::Tensor depth = values.slice(1, 2, 3) / double(kLandmarkSize) * region.width;
  const at::Tensor probabilities = at::sigmoid(values.slice(1, 3, 5));
  const at::Tensor all = at::cat({pixels, depth, probabilities}, 1);
  frame.found = true;
  frame.landmarks = all.slice(0, 0, kBodyLandmarks).contiguous();
  auxiliary = all.slice(0, kNextCentreLandmark, kNextScaleLandmark + 1).slice(1, 0, 2).contiguous();
  frame.mask =
      map_to_image(at::sigmoid(out[2].view({kLandmarkSize, kLandmarkSize})), region, image.size(0), image.size(1));
  return frame;
}

void PoseTracker::smooth(PoseFrame& frame, at::Tensor& auxiliary, double seconds) {
  const double size = 0.5 * (frame.region.width + frame.region.height);
  at::Tensor& l = frame.landmarks;
  l.slice(1, 0, 3).copy_(landmark_smoother_.apply(l.slice(1, 0, 3), seconds, size));
  // Visibility and presence: a plain low-pass.
  if (last_probabilities_.defined())
    l.slice(1, 3, 5).copy_(kProbabilitySmoothing * l.slice(1, 3, 5) +
                           (1 - kProbabilitySmoothing) * last_probabilities_);
  last_probabilities_ = l.slice(1, 3, 5).clone();
  auxiliary = auxiliary_smoother_.apply(auxiliary, seconds, size);
}

PoseFrame PoseTracker::track(const at::Tensor& image, std::optional<double> seconds) {
  TORCH_CHECK(image.dim() == 3 && image.size(2) == 3 && image.scalar_type() == at::kFloat &&
                  image.device() == detector_.device(),
              "PoseTracker: a float32 (H, W, 3) image in [0, 1] on ", detector_.device(), " expected, got ",
              describe(image));
  int64_t people = 0;
  const auto detect_now = [&]() {
    const std::optional<PersonDetection> found = detect(image);
    people = found ? found->people : 0;
    followed_ = found ? std::optional(found->region) : std::nullopt;
    forget_motion();  // a new track: nothing to smooth against
  };
  if (!followed_) detect_now();
  if (!followed_) return PoseFrame{};
  at::Tensor auxiliary;
  PoseFrame frame = landmarks_in(image, *followed_, auxiliary);
  if (!frame.found) {
    // Lost: detect again in this frame.
    detect_now();
    if (!followed_) return frame;
    frame = landmarks_in(image, *followed_, auxiliary);
    if (!frame.found) {
      followed_.reset();
      return frame;
    }
  }
  frame.people = people;
  if (options_.smooth && seconds) smooth(frame, auxiliary, *seconds);
  // Where the next frame looks: the detector's rule on this frame's two auxiliary landmarks.
  const at::Tensor a = auxiliary[0], b = auxiliary[1];
  frame.next_region =
      alignment_region(a[0].item<double>(), a[1].item<double>(), b[0].item<double>(), b[1].item<double>(), kRegionAngle)
          .scaled(kRegionScale, true);
  followed_ = frame.next_region;
  return frame;
}

}  // namespace sfgs::detect
