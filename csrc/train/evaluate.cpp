#include "train/evaluate.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <set>
#include <vector>

#include <ATen/ATen.h>

#include "animate/animator.h"
#include "io/npz.h"
#include "data/image_io.h"
#include "train/constants.h"
#include "train/run_folder.h"

namespace sfgs::train {
namespace fs = std::filesystem;

AvatarEvaluation evaluate_avatar(const data::Dataset& dataset, data::Split split, model::Avatar& avatar,
                                 const metrics::EvaluationOptions& options, const std::string& save_folder,
                                 bool overwrite) {
  const std::vector<int64_t>& frames = dataset.split(split);
  TORCH_CHECK(!frames.empty(), "dataset '", dataset.source, "' has no frames in its ", data::split_name(split),
              " split (train ", dataset.split(data::Split::kTrain).size(), ", val ",
              dataset.split(data::Split::kVal).size(), ", test ", dataset.split(data::Split::kTest).size(),
              " frames): choose another with --split");
  if (!save_folder.empty()) fs::create_directories(save_folder);
  std::set<std::string> seen_names, repeated_names;
  for (int64_t f : frames)
    if (!seen_names.insert(dataset.frames[size_t(f)].name).second)
      repeated_names.insert(dataset.frames[size_t(f)].name);
  at::NoGradGuard no_grad;
  metrics::ImageEvaluator evaluator(options);
  AvatarEvaluation result;
  const std::optional<RegionTruth> truth = read_region_truth(dataset);
  RegionAccumulator regions(options.ssim_border);
  std::map<int64_t, std::vector<size_t>> frames_of_sequence;
  std::map<int64_t, UnseenCount> unseen_of_sequence;
  int64_t previous_sequence = -1, previous_frame = -2;
  std::vector<double> render_ms;
  double person_pixels = 0, uncovered_pixels = 0;
  // Every frame through the Animator: on CUDA one graph replay per frame, whatever the frame's camera.
  animate::Animator animator(avatar, render_camera(dataset.frames[size_t(frames.front())]), at::ones({3}));
  for (size_t first = 0; first < frames.size(); first += kFramesRenderedAhead) {
    const size_t end = std::min(frames.size(), first + kFramesRenderedAhead);
    // A chunk's frames are rendered back to back and kept on the device, then compared on the CPU: a render that
    // waited for the previous frame's metrics would start on an idle GPU.
    struct RenderedFrame {
      Camera camera;
      at::Tensor image, alpha;
    };
    std::vector<RenderedFrame> rendered;
    for (size_t i = first; i < end; ++i) {
      const data::FrameRecord& record = dataset.frames[size_t(frames[i])];
      const Camera camera = render_camera(record);
      animator.set_camera(camera);
      const auto start = std::chrono::steady_clock::now();
      // The Animator returns once the frame is done (it reads the splatting's counts).
      const at::Tensor image = animator.render(record.pose, dataset.replay_time(frames[i]));
      render_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
      rendered.push_back(RenderedFrame{camera, image.clone(), animator.latest().alpha.clone()});
    }
    for (size_t i = first; i < end; ++i) {
      const int64_t f = frames[i];
      const data::FrameRecord& record = dataset.frames[size_t(f)];
      if (record.sequence != previous_sequence || f != previous_frame + 1) evaluator.begin_sequence();
      previous_sequence = record.sequence;
      previous_frame = f;
      const data::Frame frame = dataset.load(f);
      const RenderedFrame& rendered_frame = rendered[i - first];
      const at::Tensor image = rendered_frame.image.to(at::kCPU);
      {
        const at::Tensor person = frame.eval_mask >= 0.5;
        person_pixels += person.sum().item<double>();
        uncovered_pixels += (person & (rendered_frame.alpha.to(at::kCPU) < kCoveredAlpha)).sum().item<double>();
      }
      frames_of_sequence[record.sequence].push_back(result.frames.size());
      result.frames.push_back(evaluator.add_frame(image, frame.image, frame.eval_mask));
      result.frame_names.push_back(record.name);
      if (truth && !record.mesh_path.empty()) {
        const auto [compared_prediction, compared_target] =
            evaluator.compared_images(image, frame.image, frame.eval_mask);
        const std::vector<std::pair<std::string, at::Tensor>> masks =
            region_masks(*truth, io::read_npy(record.mesh_path), rendered_frame.camera, frame.eval_mask);
        regions.add(compared_prediction, compared_target, masks);
        unseen_of_sequence[record.sequence].add(labelled_person(masks), region_mask(masks, "unseen"));
      }
      if (!save_folder.empty()) {
        // Names are unique within a sequence (Dataset::validate); one that several sequences use carries its
        // sequence's.
        std::string name = repeated_names.count(record.name)
                               ? dataset.sequences[size_t(record.sequence)] + "_" + record.name
                               : record.name;
        std::replace(name.begin(), name.end(), '/', '_');
        data::write_png((fs::path(save_folder) / (name + ".png")).string(), image, overwrite);
      }
    }
  }
  result.summary = evaluator.summary();
  if (person_pixels > 0) result.uncovered_share = uncovered_pixels / person_pixels;
  result.regions = regions.summary();
  for (const auto& [sequence, indices] : frames_of_sequence) {
    GroupScore motion;
    motion.name = dataset.sequences[size_t(sequence)];
    for (size_t i : indices) {
      const metrics::FrameMetrics& m = result.frames[i];
      motion.psnr += m.psnr / double(indices.size());
      motion.ssim += m.ssim / double(indices.size());
      if (m.lpips) motion.lpips = motion.lpips.value_or(0.0) + *m.lpips / double(indices.size());
    }
    motion.frames = int64_t(indices.size());
    if (const auto it = unseen_of_sequence.find(sequence); it != unseen_of_sequence.end())
      motion.unseen_share = it->second.share();
    result.motions.push_back(motion);
  }
  result.first_render_milliseconds = render_ms.front();
  std::nth_element(render_ms.begin(), render_ms.begin() + ptrdiff_t(render_ms.size() / 2), render_ms.end());
  result.render_milliseconds = render_ms[render_ms.size() / 2];
  return result;
}

}  // namespace sfgs::train
