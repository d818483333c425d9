#include "test_trainer_utils.h"

#include <fstream>

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

}  // namespace sfgs::testing
