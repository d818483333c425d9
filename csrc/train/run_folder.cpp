#include "train/run_folder.h"

#include <filesystem>

#include <ATen/ATen.h>

#include "train/checkpoint.h"
#include "train/pose_refinement.h"

namespace sfgs::train {
namespace fs = std::filesystem;

std::string RunFolder::config_file() const { return (fs::path(path) / "config.yaml").string(); }
std::string RunFolder::checkpoint_file() const { return (fs::path(path) / "checkpoint.pt").string(); }
std::string RunFolder::log_file() const { return (fs::path(path) / "log.jsonl").string(); }
std::string RunFolder::refined_fits_file() const { return (fs::path(path) / "refined_fits.json").string(); }
std::string RunFolder::start_fits_file() const { return (fs::path(path) / "start_fits.json").string(); }
std::string RunFolder::round_folder(int64_t round) const {
  return (fs::path(path) / ("round-" + std::to_string(round))).string();
}

model::Avatar make_avatar(const TrainConfig& config, const at::Tensor& betas, at::Device device) {
  const BodyFiles& b = config.body;
  const model::AvatarBody body = b.smplx.empty() ? model::AvatarBody::procedural()
                                                 : model::AvatarBody::load(b.smplx, b.mano_left, b.mano_right,
                                                                           b.hand_vertex_ids, b.face_vertex_ids);
  model::Avatar avatar(body, betas.to(at::kFloat).cpu(), config.avatar);
  avatar->to(device);
  return avatar;
}

model::AvatarOutput pose_avatar(model::Avatar& avatar, const data::Dataset& dataset, int64_t frame) {
  TORCH_CHECK(frame >= 0 && frame < dataset.size(), "frame ", frame, " is not in dataset '", dataset.source, "' (",
              dataset.size(), " frames)");
  return avatar->forward(dataset.frames[size_t(frame)].pose, dataset.replay_time(frame));
}

body::SmplxPose clip_pose(model::Avatar& avatar, const data::MotionClip& clip, int64_t frame) {
  TORCH_CHECK(frame >= 0 && frame < static_cast<int64_t>(clip.poses.size()), "motion '", clip.source, "': frame ",
              frame, " is not in [0, ", clip.poses.size(), ")");
  return hands_for_avatar(avatar, clip.poses[size_t(frame)], clip.absolute_hands);
}

body::SmplxPose hands_for_avatar(const model::Avatar& avatar, body::SmplxPose p, bool absolute_hands) {
  if (absolute_hands == avatar->config().flat_hand_mean) return p;
  const double sign = absolute_hands ? -1.0 : 1.0;
  for (const auto& [field, side] : {std::make_pair(&body::SmplxPose::left_hand_pose, body::Side::kLeft),
                                    std::make_pair(&body::SmplxPose::right_hand_pose, body::Side::kRight)}) {
    at::Tensor& hand = p.*field;
    if (hand.defined())
      hand = hand + sign * avatar->hand_mean(side).to(hand.device(), hand.scalar_type()).view_as(hand);
  }
  return p;
}

Camera render_camera(const data::FrameRecord& frame) {
  Camera c = frame.camera;
  if (frame.pose_in_camera_frame) c.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  return c;
}

TrainedAvatar load_trained_avatar(const RunFolder& run, at::Device device) {
  TORCH_CHECK(fs::is_directory(run.path), "run folder '", run.path, "' does not exist");
  TORCH_CHECK(fs::exists(run.checkpoint_file()), "run folder '", run.path, "' has no checkpoint.pt (train it first)");
  CheckpointReader checkpoint(run.checkpoint_file());
  TrainedAvatar t;
  t.config = checkpoint.info().config;
  t.betas = checkpoint.info().betas;
  t.dataset = checkpoint.info().dataset;
  t.iteration = checkpoint.info().iteration;
  t.dataset_fingerprint = checkpoint.info().dataset_fingerprint;
  if (checkpoint.info().pose_refinement.defined() && fs::exists(run.refined_fits_file()))
    t.refined_fits = run.refined_fits_file();
  if (fs::exists(run.start_fits_file())) t.start_fits = run.start_fits_file();
  t.avatar = make_avatar(t.config, t.betas, at::kCPU);
  checkpoint.load_avatar(t.avatar);
  t.avatar->to(device);
  return t;
}

data::Dataset read_run_dataset(const TrainedAvatar& trained, const std::string& folder, bool* trained_on) {
  TORCH_CHECK(!folder.empty() || fs::is_directory(trained.dataset), "the run was trained on dataset '", trained.dataset,
              "', which is not there (moved, deleted, or a relative path from another working directory); give ",
              "the dataset's folder (--data; in Python, load_avatar(run, data=...))");
  data::Dataset dataset = data::read_dataset(folder.empty() ? trained.dataset : folder);
  // The run's dataset, as it was trained, is the one read (no start fits, or a start-fits file a run killed before its
  // first checkpoint left beside an older one) or that with the start fits; another dataset keeps its own fits.
  if (!trained.start_fits.empty() && dataset.fingerprint() != trained.dataset_fingerprint) {
    data::Dataset started = dataset;
    apply_refined_fits(started, trained.start_fits);
    if (started.fingerprint() == trained.dataset_fingerprint) dataset = std::move(started);
  }
  const bool own = trained.dataset_fingerprint.empty() || dataset.fingerprint() == trained.dataset_fingerprint;
  if (trained_on) *trained_on = own;
  if (!trained.refined_fits.empty() && own) apply_refined_fits(dataset, trained.refined_fits);
  return dataset;
}

std::string absolute_dataset_path(const data::Dataset& dataset) {
  return fs::absolute(dataset.source).lexically_normal().string();
}

}  // namespace sfgs::train
