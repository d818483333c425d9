#include "train/trainer.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>
#include <torch/optim/adam.h>
#include <torch/serialize/archive.h>
#include <unistd.h>

#include "common/atomic_file.h"
#include "metrics/image_metrics.h"
#include "train/losses.h"
#include "train/progress.h"

namespace sfgs::train {
namespace fs = std::filesystem;

namespace {

// Frames kept decoded in memory (8-bit) up to this many bytes; beyond it they are read from disk when drawn.
constexpr int64_t kFrameCacheBytes = int64_t(2) << 30;

at::Tensor string_tensor(const std::string& s) {
  return at::from_blob(const_cast<char*>(s.data()), {int64_t(s.size())}, at::kByte).clone();
}

std::string tensor_string(const at::Tensor& t) {
  const at::Tensor c = t.contiguous();
  return std::string(reinterpret_cast<const char*>(c.data_ptr<uint8_t>()), size_t(c.numel()));
}

// Training frames as 8-bit tensors (image and mask in one (H, W, 4)), decoded once.
class FrameCache {
 public:
  explicit FrameCache(const data::Dataset& dataset) : dataset_(dataset) {}
  std::pair<at::Tensor, at::Tensor> get(int64_t index, at::Device device) {
    auto it = frames_.find(index);
    at::Tensor packed;
    if (it != frames_.end()) {
      packed = it->second;
    } else {
      const data::Frame f = dataset_.load(index);
      packed = at::cat({f.image, f.mask.unsqueeze(2)}, 2).mul(255).round().to(at::kByte);
      if (bytes_ + packed.numel() <= kFrameCacheBytes) {
        bytes_ += packed.numel();
        frames_[index] = packed;
      }
    }
    const at::Tensor values = packed.to(device).to(at::kFloat).div_(255.0f);
    return {values.slice(2, 0, 3), values.select(2, 3)};
  }

 private:
  const data::Dataset& dataset_;
  std::map<int64_t, at::Tensor> frames_;
  int64_t bytes_ = 0;
};

struct Checkpoint {
  int64_t iteration = 0;
  double training_seconds = 0;
  std::string rng_state;
};

void save_checkpoint(const RunFolder& run, const TrainConfig& config, const data::Dataset& dataset,
                     const model::Avatar& avatar, torch::optim::Adam& optimizer, const Checkpoint& state) {
  torch::serialize::OutputArchive archive, avatar_archive, optimizer_archive;
  avatar->save(avatar_archive);
  optimizer.save(optimizer_archive);
  archive.write("avatar", avatar_archive);
  archive.write("optimizer", optimizer_archive);
  archive.write("iteration", at::tensor({state.iteration}, at::kLong));
  archive.write("training_seconds", at::tensor({state.training_seconds}, at::kDouble));
  archive.write("rng", string_tensor(state.rng_state));
  archive.write("config", string_tensor(config.to_yaml()));
  archive.write("dataset", string_tensor(dataset.source));
  archive.write("betas", dataset.betas.cpu());
  std::ostringstream bytes;
  archive.save_to(bytes);
  const std::string data = bytes.str();
  write_file_atomically(run.checkpoint_file(), std::vector<unsigned char>(data.begin(), data.end()), true);
}

double psnr_of(const at::Tensor& prediction, const at::Tensor& target) {
  return metrics::psnr(prediction.detach(), target).item<double>();
}

}  // namespace

double learning_rate_factor(const Schedule& schedule, int64_t iteration) {
  double factor = 1.0;
  if (schedule.warmup_iterations > 0 && iteration < schedule.warmup_iterations)
    factor = double(iteration + 1) / double(schedule.warmup_iterations);
  for (size_t i = 0; i < schedule.decay_at.size(); ++i)
    if (double(iteration) >= schedule.decay_at[i] * double(schedule.iterations)) factor = schedule.decay_factor[i];
  return factor;
}

TrainSummary train_avatar(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                          const TrainOptions& options) {
  config.validate();
  const std::vector<int64_t>& train_frames = dataset.split(data::Split::kTrain);
  TORCH_CHECK(!train_frames.empty(), "dataset '", dataset.source, "' has no training frames");
  const at::Device device(config.device == "cuda" ? at::kCUDA : at::kCPU);
  TORCH_CHECK(!device.is_cuda() || cuda_backend_available(),
              "run.device is cuda but this build of sfgs has no CUDA backend");
  fs::create_directories(run.path);
  const bool has_checkpoint = fs::exists(run.checkpoint_file());
  TORCH_CHECK(!has_checkpoint || options.resume || options.overwrite, "run folder '", run.path,
              "' already holds a checkpoint: pass --resume to continue it or --force to start afresh");
  const bool resuming = has_checkpoint && options.resume;
  const std::string config_text = config.to_yaml();
  write_file_atomically(run.config_file(), std::vector<unsigned char>(config_text.begin(), config_text.end()), true);

  torch::manual_seed(config.seed);
  model::Avatar avatar = make_avatar(config, dataset.betas, device);
  std::vector<torch::optim::OptimizerParamGroup> groups;
  {
    std::vector<at::Tensor> colour, other;
    for (const auto& p : avatar->named_parameters()) {
      (p.key().find("colour") != std::string::npos || p.key().find("rgb") != std::string::npos ? colour : other)
          .push_back(p.value());
    }
    groups.emplace_back(other, std::make_unique<torch::optim::AdamOptions>(config.schedule.learning_rate));
    if (!colour.empty())
      groups.emplace_back(colour, std::make_unique<torch::optim::AdamOptions>(config.schedule.colour_learning_rate));
  }
  torch::optim::Adam optimizer(groups, torch::optim::AdamOptions(config.schedule.learning_rate).eps(config.schedule.adam_epsilon));
  for (auto& g : optimizer.param_groups()) static_cast<torch::optim::AdamOptions&>(g.options()).eps(config.schedule.adam_epsilon);
  std::vector<double> base_rates;
  for (auto& g : optimizer.param_groups()) base_rates.push_back(static_cast<torch::optim::AdamOptions&>(g.options()).lr());

  std::mt19937_64 rng(config.seed);
  int64_t start = 0;
  double training_seconds = 0;
  if (resuming) {
    torch::serialize::InputArchive archive, avatar_archive, optimizer_archive;
    archive.load_from(run.checkpoint_file());
    archive.read("avatar", avatar_archive);
    archive.read("optimizer", optimizer_archive);
    avatar->load(avatar_archive);
    optimizer.load(optimizer_archive);
    at::Tensor iteration, rng_state;
    archive.read("iteration", iteration);
    archive.read("rng", rng_state);
    start = iteration.item<int64_t>();
    std::istringstream(tensor_string(rng_state)) >> rng;
    at::Tensor seconds;
    if (archive.try_read("training_seconds", seconds)) training_seconds = seconds.item<double>();
  } else {
    std::remove(run.log_file().c_str());
  }

  const ImageLoss image_loss(config.loss, device);
  const Regularisers regularisers(config.loss, avatar->part_labels(), avatar->faces(), device);
  JsonLinesLog log(run.log_file());
  log.write({{"event", "start"}, {"iteration", start}, {"dataset", dataset.source}, {"frames", dataset.size()},
             {"gaussians", avatar->gaussian_count()}, {"device", config.device}, {"lpips", image_loss.lpips_status()},
             {"face_loss", "skipped: the dataset has no face texture"}});
  FrameCache cache(dataset);
  std::uniform_int_distribution<size_t> pick(0, train_frames.size() - 1);
  std::uniform_real_distribution<float> colour(0.0f, 1.0f);
  ProgressBar bar(config.schedule.iterations, options.progress);
  TrainSummary summary;
  summary.validation_psnr = std::nan("");
  const auto started = std::chrono::steady_clock::now();

  // Masked PSNR (white background, evaluation mask) over at most config.validation_frames frames of a split.
  const auto split_psnr = [&](data::Split split) {
    const std::vector<int64_t>& frames = dataset.split(split);
    if (frames.empty()) return std::nan("");
    at::NoGradGuard no_grad;
    double sum = 0;
    const int64_t count = std::min<int64_t>(config.validation_frames, int64_t(frames.size()));
    for (int64_t k = 0; k < count; ++k) {
      const int64_t f = frames[size_t(k * int64_t(frames.size()) / count)];
      const data::Frame frame = dataset.load(f);
      const model::AvatarOutput out = avatar->forward(avatar_pose(dataset, f, device));
      Gaussians g{out.means, {}, {}, out.covariances, out.opacities, out.colours};
      const at::Tensor white = at::ones({3}, out.means.options());
      const RenderResult r = render(g, white, render_camera(dataset.frames[size_t(f)]));
      const at::Tensor mask = frame.eval_mask.to(device).unsqueeze(2);
      const at::Tensor gt = frame.image.to(device) * mask + (1 - mask);
      sum += psnr_of(r.image * mask + (1 - mask), gt);
    }
    return sum / double(count);
  };
  const auto validate = [&](int64_t iteration) {
    const double val = split_psnr(data::Split::kVal), test = split_psnr(data::Split::kTest);
    if (std::isnan(val) && std::isnan(test)) return;
    summary.validation_psnr = val;
    nlohmann::json entry{{"event", "validation"}, {"iteration", iteration}, {"training_seconds", training_seconds}};
    if (!std::isnan(val)) entry["val_psnr"] = val;
    if (!std::isnan(test)) entry["test_psnr"] = test;
    log.write(entry);
  };

  const int64_t end = options.stop_at > 0 ? std::min(options.stop_at, config.schedule.iterations)
                                          : config.schedule.iterations;
  TORCH_CHECK(end > start || start == config.schedule.iterations, "train: --stop-at ", options.stop_at,
              " is not past the checkpoint's iteration ", start);
  for (int64_t it = start; it < end; ++it) {
    const auto step_started = std::chrono::steady_clock::now();
    const double factor = learning_rate_factor(config.schedule, it);
    for (size_t g = 0; g < base_rates.size(); ++g)
      static_cast<torch::optim::AdamOptions&>(optimizer.param_groups()[g].options()).lr(base_rates[g] * factor);
    const int64_t f = train_frames[pick(rng)];
    const auto [image, mask] = cache.get(f, device);
    const float bg_values[3] = {colour(rng), colour(rng), colour(rng)};
    const at::Tensor background = at::tensor(std::vector<float>(bg_values, bg_values + 3), at::kFloat).to(device);
    const at::Tensor m = mask.unsqueeze(2);
    const at::Tensor target = image * m + background * (1 - m);

    const model::AvatarOutput out = avatar->forward(avatar_pose(dataset, f, device));
    Gaussians g{out.means, {}, {}, out.covariances, out.opacities, out.colours};
    const RenderResult r = render(g, background, render_camera(dataset.frames[size_t(f)]));
    LossTerms terms;
    image_loss.add_terms(r.image, target, terms);
    regularisers.add_terms(out, terms);
    const at::Tensor loss = total_loss(terms);
    optimizer.zero_grad();
    loss.backward();
    optimizer.step();
    const int64_t done = it + 1;
    const bool logs = done % config.log_every == 0 || done == end;
    // The loss values are read on logged steps only: reading them is a host sync on a GPU.
    const double step_psnr = logs ? psnr_of(r.image, target) : 0.0;
    training_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - step_started).count();

    if (logs) {
      nlohmann::json entry{{"event", "step"},          {"iteration", done}, {"lr_factor", factor},
                           {"psnr", step_psnr},         {"seconds", bar.elapsed_seconds()},
                           {"training_seconds", training_seconds}};
      for (const auto& [name, value] : terms) entry["loss"][name] = value.item<double>();
      log.write(entry);
      summary.final_loss = terms["total"].item<double>();
      bar.update(done, summary.final_loss, entry["psnr"].get<double>());
    }
    if (done % config.validate_every == 0 || done == end) validate(done);
    if (done % config.checkpoint_every == 0 || done == end) {
      std::ostringstream rng_state;
      rng_state << rng;
      save_checkpoint(run, config, dataset, avatar, optimizer, Checkpoint{done, training_seconds, rng_state.str()});
    }
  }
  bar.finish();
  summary.iterations = std::max(start, end);
  summary.training_seconds = training_seconds;
  summary.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  nlohmann::json end_entry{{"event", "end"},
                            {"iteration", summary.iterations},
                            {"seconds", summary.seconds},
                            {"training_seconds", training_seconds}};
  if (!std::isnan(summary.validation_psnr)) end_entry["val_psnr"] = summary.validation_psnr;
  log.write(end_entry);
  return summary;
}

std::vector<ErrorCurvePoint> write_error_curve_csv(const RunFolder& run, const std::string& csv_path) {
  std::ifstream in(run.log_file());
  TORCH_CHECK(in, "cannot read the training log '", run.log_file(), "'");
  std::map<int64_t, ErrorCurvePoint> rows;
  std::string line;
  const auto number = [](const nlohmann::json& e, const char* key) {
    return e.contains(key) && e[key].is_number() ? e[key].get<double>() : std::nan("");
  };
  while (std::getline(in, line)) {
    const nlohmann::json e = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
    if (!e.is_object() || e.value("event", "") != "validation" || !e.contains("iteration")) continue;
    const int64_t iteration = e["iteration"].get<int64_t>();
    rows[iteration] = {iteration, number(e, "training_seconds"), number(e, "val_psnr"), number(e, "test_psnr")};
  }
  std::ostringstream csv;
  csv << "iteration,training_seconds,val_psnr,test_psnr\n";
  const auto cell = [](double v) { return std::isnan(v) ? std::string() : std::to_string(v); };
  std::vector<ErrorCurvePoint> points;
  for (const auto& [iteration, p] : rows) {
    csv << iteration << ',' << cell(p.training_seconds) << ',' << cell(p.val_psnr) << ',' << cell(p.test_psnr) << '\n';
    points.push_back(p);
  }
  const std::string text = csv.str();
  write_file_atomically(csv_path, std::vector<unsigned char>(text.begin(), text.end()), true);
  return points;
}

}  // namespace sfgs::train
