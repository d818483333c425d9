#include "test_trainer_utils.h"

#include <fstream>

#include "data/image_io.h"
#include "data/synthetic.h"
#include "test_avatar_utils.h"

namespace sfgs::testing {

train::TrainConfig tiny_train_config() {
  train::TrainConfig c;
  c.avatar = small_config();
  c.loss.use_lpips = false;
  c.schedule.iterations = 6;
  c.schedule.warmup_iterations = 2;
  c.log_every = 1;
  c.validate_every = 2;
  c.checkpoint_every = 100;  // only a pause and the end write one
  c.validation_frames = 1;
  return c;
}

data::Dataset tiny_video(const TempFolder& folder, int64_t frames, int64_t side, const std::string& name,
                         uint64_t seed) {
  data::SyntheticVideoOptions o;
  o.frames = frames;
  o.width = side;
  o.height = side;
  o.seed = seed;
  return data::write_synthetic_video(folder / name, o);
}

train::TrainOptions quiet() {
  train::TrainOptions o;
  o.progress = false;
  return o;
}

std::vector<nlohmann::json> log_entries(const train::RunFolder& run) {
  std::vector<nlohmann::json> entries;
  std::ifstream in(run.log_file());
  for (std::string line; std::getline(in, line);) entries.push_back(nlohmann::json::parse(line));
  return entries;
}

model::Avatar render_frames_with_avatar(data::Dataset& dataset, const std::vector<int64_t>& frames) {
  model::Avatar avatar(procedural_avatar_body(), dataset.betas, small_config());
  randomise_parameters(*avatar, 0.3, 42);  // colours that vary over the body
  avatar->eval();
  avatar->cache_static_features();
  at::NoGradGuard no_grad;
  for (const int64_t f : frames) {
    data::FrameRecord& record = dataset.frames[size_t(f)];
    const model::AvatarOutput out = avatar->forward(record.pose, dataset.replay_time(f));
    const RenderResult r = render(model::to_gaussians(out), at::ones({3}), train::render_camera(record));
    data::write_png(record.image_path, r.image, true);
    data::write_png(record.mask_path, (r.alpha > 0.5).to(at::kFloat), true);
    record.mask_encoding = data::MaskEncoding::kWhitePerson;
    record.true_pose = record.pose;
  }
  return avatar;
}

}  // namespace sfgs::testing
