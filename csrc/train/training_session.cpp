#include "train/training_session.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <sstream>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "common/device_graph.h"
#include "common/stage_timer.h"
#include "metrics/image_metrics.h"

namespace sfgs::train {

namespace {

// A CPU run whose first step says it will take longer than this gets a warning with the estimate and the ways to a
// shorter one (the default config is sized for a GPU: on two cores it would run for days).
constexpr double kLongCpuRunSeconds = 3600;

torch::optim::AdamOptions& adam_options(torch::optim::Adam& optimizer, size_t group) {
  return static_cast<torch::optim::AdamOptions&>(optimizer.param_groups()[group].options());
}

}  // namespace

TrainingSession::TrainingSession(const data::Dataset& dataset, const TrainConfig& config, const RunFolder& run,
                                 const TrainOptions& options)
    : dataset_(dataset),
      config_(config),
      run_(run),
      options_(options),
      device_(config.device == "cuda" ? at::kCUDA : at::kCPU),
      tf32_(config.schedule.tf32_matmul),
      replay_clock_(dataset),
      rng_(config.seed) {
  torch::manual_seed(config.seed);
  avatar_ = make_avatar(config, dataset.betas, device_);
  optimizer_ = make_optimizer(avatar_, config.schedule);
  adam_ = std::make_unique<AdamStepper>(*optimizer_, config.schedule.fused_adam);
  for (size_t g = 0; g < optimizer_->param_groups().size(); ++g)
    base_rates_.push_back(adam_options(*optimizer_, g).lr());
  image_loss_ = std::make_unique<ImageLoss>(config.loss, device_);
  regularisers_ = std::make_unique<Regularisers>(config.loss, avatar_->part_labels(), avatar_->faces(), device_);
  frames_ = std::make_unique<FrameCache>(dataset, dataset.split(data::Split::kTrain), device_.is_cuda());
  step_ = std::make_unique<TrainingStep>(avatar_, *image_loss_, *regularisers_);
  parts_ = make_training_parts(dataset, config, avatar_->gaussian_count(), device_);
  // A benchmark's stage recorder times stages by synchronising, which a graph cannot hold. Pose refinement's alignment
  // passes run between recorded steps, and a step trains on the fits the last pass left, uploaded like any frame's.
  if (device_.is_cuda() && config.schedule.cuda_graphs && device_graphs_available() && !stage_recorder_installed())
    graphs_ = std::make_unique<StepGraphs>(avatar_, device_);
  summary_.validation_psnr = std::nan("");
  summary_.has_validation_frames = !dataset.split(data::Split::kVal).empty();
}

TrainingSession::~TrainingSession() = default;

void TrainingSession::restore(CheckpointReader& checkpoint) {
  checkpoint.load_avatar(avatar_);
  // The records go back to their part, not to the avatar (train/training_records.h).
  avatar_->set_observation(at::Tensor());
  avatar_->set_sampling_record(at::Tensor());
  checkpoint.load_optimizer(*optimizer_);
  // The schedule may have changed on resume: the groups take the config's rates, not the checkpoint's.
  for (size_t g = 0; g < base_rates_.size(); ++g) adam_options(*optimizer_, g).eps(config_.schedule.adam_epsilon);
  std::istringstream(checkpoint.info().rng_state) >> rng_;
  training_seconds_ = checkpoint.info().training_seconds;
  last_checkpoint_ = checkpoint.info().iteration;
  for (const auto& part : parts_) part->restore(checkpoint.info(), run_.checkpoint_file());
}

void TrainingSession::add_part(std::unique_ptr<TrainingPart> part) { parts_.push_back(std::move(part)); }

void TrainingSession::open_log() {
  log_ = std::make_unique<JsonLinesLog>(run_.log_file());
  log_->write({{"event", "start"},
               {"iteration", last_checkpoint_ < 0 ? 0 : last_checkpoint_},
               {"dataset", dataset_.source},
               {"frames", dataset_.size()},
               {"gaussians", avatar_->gaussian_count()},
               {"device", config_.device},
               {"lpips", image_loss_->lpips_status()}});
}

void TrainingSession::step(int64_t it) {
  const double factor = learning_rate_factor(config_.schedule, it);
  for (size_t g = 0; g < base_rates_.size(); ++g) adam_options(*optimizer_, g).lr(base_rates_[g] * factor);
  const std::vector<int64_t>& train_frames = dataset_.split(data::Split::kTrain);
  std::uniform_int_distribution<size_t> pick(0, train_frames.size() - 1);
  std::uniform_real_distribution<float> colour(0.0f, 1.0f);
  const int64_t f = train_frames[pick(rng_)];
  const data::FrameRecord& record = dataset_.frames[size_t(f)];
  for (const auto& part : parts_) {
    const nlohmann::json entry = part->before_step(it, avatar_);
    if (!entry.empty()) log_->write(entry);
  }
  StepData data;
  data.background = {colour(rng_), colour(rng_), colour(rng_)};
  data.pose = record.pose;
  data.camera = render_camera(record);
  // The time branch is a residual that new motions go without: some steps train without it (docs/avatar.md).
  data.time = replay_clock_.time_of(record);
  if (std::uniform_real_distribution<double>(0.0, 1.0)(rng_) < config_.avatar.time_dropout) data.time.reset();
  // LPIPS in every lpips_every-th step; the steps between report its last value (a resumed run measures first).
  data.lpips = it % config_.loss.lpips_every == 0 || !last_lpips_.defined();
  {
    const StageScope stage("train: frame (kept or decoded)");
    data.frame = frames_->get(f);
  }
  for (const auto& part : parts_) part->prepare_step(f, data);

  StepOutputs outputs;
  if (graphs_) {
    try {
      outputs = graphs_->run(data, [&](const StepInputs& in) { return step_->run(in, data.lpips); });
    } catch (const StepRecordingError& e) {
      // A step the graphs cannot hold is still a step: the run goes on eagerly, and the log says why.
      log_->write({{"event", "graphs_off"}, {"iteration", it}, {"message", e.what()}});
      graphs_.reset();
    }
  }
  if (!graphs_) {
    StepInputs inputs(data, device_);
    inputs.upload(data);
    outputs = step_->run(inputs, data.lpips);
  }
  {
    const StageScope stage("train: optimizer");
    adam_->step(outputs.skip_update);
  }
  for (const auto& part : parts_) part->after_step(outputs);
  LossTerms& terms = outputs.terms;
  // A copy: a recorded step rewrites its outputs at every replay.
  if (terms.count("lpips"))
    last_lpips_ = terms["lpips"].clone();
  else if (last_lpips_.defined())
    terms["lpips"] = last_lpips_;
  watch_.record(it + 1, terms, {{"psnr", outputs.psnr}});
}

TrainSummary TrainingSession::run(int64_t start, int64_t end) {
  TORCH_CHECK(log_, "TrainingSession: open_log() first");
  bar_ = std::make_unique<ProgressBar>(config_.schedule.iterations, options_.progress);
  const auto started = std::chrono::steady_clock::now();
  const double seconds_before = training_seconds_;
  summary_.first_iteration = start;
  for (int64_t it = start; it < end; ++it) {
    const auto step_started = std::chrono::steady_clock::now();
    {
      const StageScope stage("train: step");
      step(it);
    }
    const double step_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - step_started).count();
    training_seconds_ += step_seconds;
    if (it == start) warn_if_long(step_seconds, config_.schedule.iterations - start);
    finish_step(it + 1, end);
  }
  bar_->finish();
  summary_.iterations = std::max(start, end);
  summary_.steps = end - start;
  summary_.finished = summary_.iterations == config_.schedule.iterations;
  summary_.training_seconds = training_seconds_;
  summary_.step_seconds = training_seconds_ - seconds_before;
  summary_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  nlohmann::json entry{{"event", "end"},
                       {"iteration", summary_.iterations},
                       {"seconds", summary_.seconds},
                       {"training_seconds", training_seconds_}};
  if (graphs_) {
    graphs_->settle();  // the last steps' counts, so that every overflow is counted
    const StepGraphStats& g = graphs_->stats();
    entry["step_graphs"] = {{"captures", g.captures},
                            {"replays", g.replays},
                            {"eager_steps", g.eager_steps},
                            {"budget_overflows", g.budget_overflows},
                            {"intersection_budget", g.intersection_budget}};
  }
  if (!std::isnan(summary_.validation_psnr)) entry["val_psnr"] = summary_.validation_psnr;
  log_->write(entry);
  return summary_;
}

void TrainingSession::warn_if_long(double first_step_seconds, int64_t remaining) {
  const double estimate = first_step_seconds * double(remaining);
  if (device_.is_cuda() || estimate < kLongCpuRunSeconds) return;
  log_->write({{"event", "estimate"},
               {"first_step_seconds", first_step_seconds},
               {"remaining_iterations", remaining},
               {"estimated_seconds", estimate}});
  if (!options_.progress) return;
  std::fprintf(stderr,
               "sfgs train: the first step took %.1f s on the CPU: the run's %lld remaining iterations would take "
               "about %s.\n  For a run of minutes: --config configs/demo.yaml (the demo's small avatar), fewer "
               "iterations (--iterations N, or --stop-at N and --resume later), or --device cuda on a machine with a "
               "GPU.\n",
               first_step_seconds, (long long)remaining, format_duration(estimate).c_str());
}

void TrainingSession::finish_step(int64_t done, int64_t end) {
  const bool logs = done % config_.log_every == 0 || done == end;
  const bool validates = done % config_.validate_every == 0 || done == end;
  const bool checkpoints = done % config_.checkpoint_every == 0 || done == end;
  // Reading the watched losses is the step's host synchronisation on a GPU: only where one happens anyway.
  if (!(logs || validates || checkpoints)) return;
  std::map<std::string, double> latest;
  try {
    latest = watch_.read();
  } catch (const DivergenceError& e) {
    stop_diverged(e);
  }
  if (logs) {
    nlohmann::json entry{{"event", "step"},
                         {"iteration", done},
                         {"lr_factor", learning_rate_factor(config_.schedule, done - 1)},
                         {"psnr", latest["psnr"]},
                         {"seconds", bar_->elapsed_seconds()},
                         {"training_seconds", training_seconds_}};
    for (const auto& [name, value] : latest)
      if (name != "psnr") entry["loss"][name] = value;
    log_->write(entry);
    summary_.final_loss = latest["total"];
    bar_->update(done, summary_.final_loss, latest["psnr"]);
  }
  if (validates) validate(done);
  if (checkpoints) checkpoint(done);
}

double TrainingSession::split_psnr(data::Split split) {
  const std::vector<int64_t>& frames = dataset_.split(split);
  if (frames.empty()) return std::nan("");
  at::NoGradGuard no_grad;
  double sum = 0;
  const int64_t count = std::min<int64_t>(config_.validation_frames, int64_t(frames.size()));
  for (int64_t k = 0; k < count; ++k) {
    const int64_t f = frames[size_t(k * int64_t(frames.size()) / count)];
    const data::Frame frame = dataset_.load(f);
    const model::AvatarOutput out = pose_avatar(avatar_, dataset_, f);
    const at::Tensor white = at::ones({3}, out.means.options());
    const RenderResult r = render(to_gaussians(out), white, render_camera(dataset_.frames[size_t(f)]));
    const at::Tensor mask = frame.eval_mask.to(device_).unsqueeze(2);
    const at::Tensor gt = frame.image.to(device_) * mask + (1 - mask);
    sum += metrics::psnr(r.image * mask + (1 - mask), gt).item<double>();
  }
  return sum / double(count);
}

void TrainingSession::validate(int64_t done) {
  const double val = split_psnr(data::Split::kVal), test = split_psnr(data::Split::kTest);
  if (std::isnan(val) && std::isnan(test)) return;
  summary_.validation_psnr = val;
  nlohmann::json entry{{"event", "validation"}, {"iteration", done}, {"training_seconds", training_seconds_}};
  if (!std::isnan(val)) entry["val_psnr"] = val;
  if (!std::isnan(test)) entry["test_psnr"] = test;
  for (const auto& part : parts_) part->describe_validation(entry);
  log_->write(entry);
}

void TrainingSession::checkpoint(int64_t done) {
  CheckpointInfo info;
  info.iteration = done;
  info.training_seconds = training_seconds_;
  std::ostringstream rng_state;
  rng_state << rng_;
  info.rng_state = rng_state.str();
  info.config = config_;
  info.dataset = absolute_dataset_path(dataset_);
  info.dataset_fingerprint = dataset_.fingerprint();
  info.betas = dataset_.betas.to(at::kFloat).cpu();
  for (const auto& part : parts_) part->save(info);
  try {
    save_checkpoint(run_.checkpoint_file(), info, avatar_, *optimizer_);
    for (const auto& part : parts_) part->write_beside_checkpoint(run_);
  } catch (const std::runtime_error& e) {
    if (first_non_finite_tensor(*avatar_).empty()) throw;
    stop_diverged(
        DivergenceError(done, std::string("training diverged by iteration ") + std::to_string(done) + ": " + e.what()));
  }
  last_checkpoint_ = done;
}

void TrainingSession::stop_diverged(const DivergenceError& e) {
  bar_->finish();
  const std::string kept = last_checkpoint_ < 0
                               ? "no checkpoint had been written yet"
                               : "the run keeps its last good checkpoint (iteration " +
                                     std::to_string(last_checkpoint_) + ", " + run_.checkpoint_file() + ")";
  const std::string message =
      std::string(e.what()) + "; " + kept +
      ". Lower schedule.learning_rate or check the data; then --resume, or --force to start over";
  log_->write({{"event", "error"}, {"iteration", e.iteration()}, {"message", message}});
  throw DivergenceError(e.iteration(), message);
}

}  // namespace sfgs::train
