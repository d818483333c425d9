#include "train/run_folder.h"

#include <filesystem>

#include <ATen/ATen.h>
#include <torch/serialize/archive.h>

namespace sfgs::train {
namespace fs = std::filesystem;

std::string RunFolder::config_file() const { return (fs::path(path) / "config.yaml").string(); }
std::string RunFolder::checkpoint_file() const { return (fs::path(path) / "checkpoint.pt").string(); }
std::string RunFolder::log_file() const { return (fs::path(path) / "log.jsonl").string(); }

model::Avatar make_avatar(const TrainConfig& config, const at::Tensor& betas, at::Device device) {
  const BodyFiles& b = config.body;
  const model::AvatarBody body = b.smplx.empty() ? model::AvatarBody::procedural()
                                                 : model::AvatarBody::load(b.smplx, b.mano_left, b.mano_right,
                                                                           b.hand_vertex_ids, b.face_vertex_ids);
  model::Avatar avatar(body, betas.to(at::kFloat).cpu(), config.avatar);
  avatar->to(device);
  return avatar;
}

namespace {

model::AvatarPose to_avatar_pose(const data::SmplxPose& p, double time, at::Device device) {
  model::AvatarPose pose;
  pose.global_orient = p.global_orient.to(device);
  pose.body_pose = p.body_pose.to(device);
  pose.jaw_pose = p.jaw_pose.to(device);
  pose.left_eye_pose = p.left_eye_pose.to(device);
  pose.right_eye_pose = p.right_eye_pose.to(device);
  pose.left_hand_pose = p.left_hand_pose.to(device);
  pose.right_hand_pose = p.right_hand_pose.to(device);
  pose.expression = p.expression.to(device);
  pose.transl = p.transl.to(device);
  pose.time = time;
  return pose;
}

}  // namespace

model::AvatarPose avatar_pose(const data::Dataset& dataset, int64_t frame, at::Device device) {
  return to_avatar_pose(dataset.frames[size_t(frame)].pose, dataset.normalized_time(frame), device);
}

model::AvatarPose rest_pose(int64_t expression_count, at::Device device) {
  return to_avatar_pose(data::SmplxPose::zeros(expression_count), 0.0, device);
}

Camera render_camera(const data::FrameRecord& frame) {
  Camera c = frame.camera;
  if (frame.pose.in_camera_frame) c.world_to_camera = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  return c;
}

TrainedAvatar load_trained_avatar(const RunFolder& run, at::Device device) {
  TORCH_CHECK(fs::exists(run.checkpoint_file()), "run folder '", run.path, "' has no checkpoint.pt (train it first)");
  TrainedAvatar t;
  torch::serialize::InputArchive archive, avatar_archive;
  try {
    archive.load_from(run.checkpoint_file());
  } catch (const c10::Error& e) {
    TORCH_CHECK(false, "'", run.checkpoint_file(), "' is not a readable sfgs checkpoint: ", e.what_without_backtrace());
  }
  at::Tensor config_text, dataset, iteration;
  archive.read("config", config_text);
  archive.read("dataset", dataset);
  archive.read("iteration", iteration);
  archive.read("betas", t.betas);
  const at::Tensor c = config_text.contiguous();
  t.config = TrainConfig::from_yaml_text(std::string(reinterpret_cast<const char*>(c.data_ptr<uint8_t>()), size_t(c.numel())),
                                         run.checkpoint_file());
  const at::Tensor d = dataset.contiguous();
  t.dataset = std::string(reinterpret_cast<const char*>(d.data_ptr<uint8_t>()), size_t(d.numel()));
  t.iteration = iteration.item<int64_t>();
  t.avatar = make_avatar(t.config, t.betas, device);
  archive.read("avatar", avatar_archive);
  t.avatar->load(avatar_archive);
  t.avatar->to(device);
  return t;
}

}  // namespace sfgs::train
