// Person detection on CUDA (csrc/detect/): each network's recorded runs (CUDA graphs) equal its eager runs for new
// inputs and leave earlier results alone; on frames of a synthetic person waving at 540 x 960, the trackers and part
// networks run on the GPU (the device named without an index, as `sfgs prepare --device cuda` names it) find what
// the CPU's find: the same people, whole-body keypoints a few thousandths of a pixel apart (median), the same person
// mask. Skips without a CUDA device or the MediaPipe models; the stand-in person of ../shared when present, else the
// built-in body.
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <torch/cuda.h>

#include "common/atomic_file.h"
#include "detect/parts.h"
#include "detect/models.h"
#include "detect/pose_tracker.h"
#include "detect/tflite_network.h"
#include "detect/wholebody.h"
#include "test_body_utils.h"
#include "tensor_compare.h"
#include "test_detect_utils.h"

namespace sfgs::testing {
namespace {

struct Detected {
  bool found = false;
  at::Tensor keypoints;  // (133, 3) on the CPU
  at::Tensor mask;       // (H, W) bool on the CPU
};

Detected detect_on(detect::PoseTracker& tracker, const detect::PartsLandmarker& parts, const at::Tensor& image,
                   double seconds) {
  Detected d;
  const detect::PoseFrame pose = tracker.track(image, seconds);
  d.found = pose.found;
  if (!pose.found) return d;
  d.keypoints =
      detect::wholebody_keypoints(pose, parts.face(image, pose), parts.hand(image, pose, detect::HandSide::kLeft),
                                  parts.hand(image, pose, detect::HandSide::kRight))
          .cpu();
  d.mask = (pose.mask > 0.5).cpu();
  return d;
}

// Every network prepare runs, recorded and replayed against run eagerly: a second input (not the one recorded with)
// gives the eager outputs, and the first call's outputs are still its own after the second.
TEST(DetectCuda, RecordedNetworksEqualEagerRunsForNewInputs) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  SFGS_SKIP_WITHOUT_MEDIAPIPE_MODELS();
  for (const char* file : {"pose_detection.tflite", "pose_landmark_full.tflite", "face_detection_short_range.tflite",
                           "face_landmark.tflite", "hand_recrop.tflite", "hand_landmark_full.tflite"}) {
    const std::string path = detect::mediapipe_model(file);
    const detect::TfliteNetwork recorded = detect::TfliteNetwork::load(path, at::kCUDA, true);
    const detect::TfliteNetwork eager = detect::TfliteNetwork::load(path, at::kCUDA, false);
    std::vector<int64_t> shape = recorded.input_shape();
    shape[0] = 1;
    at::manual_seed(3);
    const at::Tensor first = at::rand(shape, at::kCUDA), second = at::rand(shape, at::kCUDA);
    const std::vector<at::Tensor> from_first = recorded.run({first});
    const std::vector<at::Tensor> from_second = recorded.run({second});
    const std::vector<at::Tensor> eager_first = eager.run({first}), eager_second = eager.run({second});
    ASSERT_EQ(from_second.size(), eager_second.size()) << file;
    for (size_t k = 0; k < eager_second.size(); ++k) {
      const double scale = 1 + eager_second[k].abs().max().item<double>();
      EXPECT_LT(max_difference(from_second[k], eager_second[k]) / scale, 1e-5) << file << " output " << k;
      EXPECT_LT(max_difference(from_first[k], eager_first[k]) / scale, 1e-5) << file << " output " << k << ", kept";
    }
  }
}

TEST(DetectCuda, WholeBodyKeypointsAndMaskEqualTheCpus) {
  if (!torch::cuda::is_available()) GTEST_SKIP() << "no CUDA device";
  SFGS_SKIP_WITHOUT_MEDIAPIPE_MODELS();
  const std::string bodies = shared_bodies_folder();
  const std::filesystem::path folder =
      std::filesystem::temp_directory_path() / ("sfgs_detect_cuda_" + std::to_string(::getpid()));
  const data::Dataset video = person_video(folder, bodies, "wave", 3, 540, 960);
  detect::PoseTracker cpu_tracker(at::kCPU), gpu_tracker(at::Device(at::kCUDA));
  const detect::PartsLandmarker cpu_parts(at::kCPU), gpu_parts(at::Device(at::kCUDA));
  std::vector<double> distances;
  for (int64_t f = 0; f < video.size(); ++f) {
    const at::Tensor image = video.load(f).image;
    const double seconds = video.frames[size_t(f)].time;
    const Detected on_cpu = detect_on(cpu_tracker, cpu_parts, image, seconds);
    const Detected on_gpu = detect_on(gpu_tracker, gpu_parts, image.to(at::kCUDA), seconds);
    ASSERT_TRUE(on_cpu.found) << "frame " << f;
    ASSERT_TRUE(on_gpu.found) << "frame " << f;
    // The same points found (a score of 0 is a part not found), at the same places.
    const at::Tensor cpu_seen = on_cpu.keypoints.select(1, 2) > 0, gpu_seen = on_gpu.keypoints.select(1, 2) > 0;
    EXPECT_TRUE(cpu_seen.equal(gpu_seen)) << "frame " << f;
    const at::Tensor both = (cpu_seen & gpu_seen).nonzero().view({-1});
    const at::Tensor apart =
        (on_cpu.keypoints.index_select(0, both).slice(1, 0, 2) - on_gpu.keypoints.index_select(0, both).slice(1, 0, 2))
            .norm(2, 1)
            .to(at::kDouble)
            .contiguous();
    distances.insert(distances.end(), apart.data_ptr<double>(), apart.data_ptr<double>() + apart.numel());
    const double iou =
        (on_cpu.mask & on_gpu.mask).sum().item<double>() / (on_cpu.mask | on_gpu.mask).sum().item<double>();
    EXPECT_GT(iou, 0.99) << "frame " << f;
  }
  remove_tree(folder.string());
  ASSERT_FALSE(distances.empty());
  std::sort(distances.begin(), distances.end());
  std::printf("CUDA against CPU: %zu points, median %.3f px, largest %.3f px\n", distances.size(),
              distances[distances.size() / 2], distances.back());
  // Measured on an H200: median 0.003 px, largest 0.99 px (with TF32 convolutions: 0.31 and 6.9 px).
  EXPECT_LT(distances[distances.size() / 2], 0.05);
  EXPECT_LT(distances.back(), 2.0);
}

}  // namespace
}  // namespace sfgs::testing
