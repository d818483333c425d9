// No silent failures and no lost runs: a diverging run stops naming the iteration and term and keeps its last good
// checkpoint; damaged checkpoints are refused by name; a resume keeps the run's model and data and rewrites nothing
// it refuses; a run folder has one trainer at a time; killed runs leave nothing that lingers.
#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>

#include <ATen/ATen.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <torch/optim/adam.h>
#include <unistd.h>

#include "common/atomic_file.h"
#include "common/background_jobs.h"
#include "common/folder_lock.h"
#include "test_avatar_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/checkpoint.h"
#include "train/loss_watch.h"
#include "train/rounds.h"
#include "train/trainer.h"

namespace sfgs::testing {
namespace {

namespace fs = std::filesystem;

// The shared tiny config, warming up in one step and validating only at the end.
train::TrainConfig tiny_config() {
  train::TrainConfig c = tiny_train_config();
  c.schedule.warmup_iterations = 1;
  c.validate_every = 100;
  return c;
}

data::Dataset six_frame_video(const TempFolder& folder, const std::string& name = "video", uint64_t seed = 1) {
  return testing::tiny_video(folder, 6, 24, name, seed);
}

std::string file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void write_bytes(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

// A run paused at iteration 3 of 6.
train::RunFolder paused_run(const TempFolder& folder, const data::Dataset& dataset) {
  const train::RunFolder run{folder / "run"};
  train::TrainOptions pause = quiet();
  pause.stop_at = 3;
  train::train_avatar(dataset, tiny_config(), run, pause);
  return run;
}

TEST(LossWatch, NamesTheFirstNonFiniteIterationAndTerm) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  train::LossWatch watch;
  const auto terms = [](double image, double lab) {
    train::LossTerms t;
    t["image"] = at::scalar_tensor(image);
    t["lab"] = at::scalar_tensor(lab);
    t["total"] = at::scalar_tensor(image + lab);
    return t;
  };
  const train::LossTerms psnr{{"psnr", at::scalar_tensor(std::numeric_limits<double>::infinity())}};
  watch.record(1, terms(0.5, 0.25), psnr);
  const auto latest = watch.read();
  EXPECT_DOUBLE_EQ(latest.at("total"), 0.75);
  EXPECT_TRUE(std::isinf(latest.at("psnr")));  // reported, not checked: a perfect match is +Inf dB
  watch.record(2, terms(0.5, 0.25), psnr);
  watch.record(3, terms(0.5, nan), psnr);
  watch.record(4, terms(nan, nan), psnr);
  try {
    watch.read();
    ADD_FAILURE() << "expected a DivergenceError";
  } catch (const train::DivergenceError& e) {
    EXPECT_EQ(e.iteration(), 3);
    EXPECT_EQ(std::string(e.what()), "training diverged at iteration 3: loss 'lab' = nan, 'total' = nan is not finite");
  }
}

// A run whose optimiser state is poisoned (finite, but its second moments negative: every update is NaN) must stop at
// the first non-finite loss, name it, log it, and leave the checkpoint it resumed from untouched.
TEST(TrainerDivergence, StopsAtTheFirstNonFiniteLossAndKeepsTheLastGoodCheckpoint) {
  TempFolder folder;
  const data::Dataset dataset = six_frame_video(folder);
  const train::RunFolder run = paused_run(folder, dataset);
  {
    train::CheckpointReader reader(run.checkpoint_file());
    train::CheckpointInfo info = reader.info();
    model::Avatar avatar = train::make_avatar(info.config, info.betas, at::kCPU);
    reader.load_avatar(avatar);
    auto optimizer = train::make_optimizer(avatar, info.config.schedule);
    reader.load_optimizer(*optimizer);
    for (auto& entry : optimizer->state())
      static_cast<torch::optim::AdamParamState&>(*entry.second).exp_avg_sq().fill_(-1.0);
    train::save_checkpoint(run.checkpoint_file(), info, avatar, *optimizer);
  }
  const std::string good = file_bytes(run.checkpoint_file());
  train::TrainOptions resume = quiet();
  resume.resume = true;
  try {
    train::train_avatar(dataset, tiny_config(), run, resume);
    ADD_FAILURE() << "expected the run to stop";
  } catch (const train::DivergenceError& e) {
    EXPECT_EQ(e.iteration(), 5);  // step 4 used the good parameters and produced NaN ones
    const std::string message = e.what();
    EXPECT_NE(message.find("training diverged at iteration 5: loss"), std::string::npos) << message;
    EXPECT_NE(message.find("'total' = nan"), std::string::npos) << message;
    EXPECT_NE(message.find("keeps its last good checkpoint (iteration 3"), std::string::npos) << message;
  }
  EXPECT_EQ(file_bytes(run.checkpoint_file()), good);
  const auto entries = log_entries(run);
  ASSERT_FALSE(entries.empty());
  EXPECT_EQ(entries.back()["event"], "error");
  EXPECT_EQ(entries.back()["iteration"], 5);
}

TEST(Checkpoint, RefusesToWriteNonFiniteParameters) {
  TempFolder folder;
  const data::Dataset dataset = six_frame_video(folder);
  const train::TrainConfig config = tiny_config();
  model::Avatar avatar = train::make_avatar(config, dataset.betas, at::kCPU);
  auto optimizer = train::make_optimizer(avatar, config.schedule);
  {
    at::NoGradGuard no_grad;
    avatar->named_parameters()["heads.colour.output_bias"][1] = std::numeric_limits<float>::infinity();
  }
  train::CheckpointInfo info;
  info.config = config;
  info.betas = dataset.betas;
  const std::string path = folder / "checkpoint.pt";
  expect_error_mentioning([&] { train::save_checkpoint(path, info, avatar, *optimizer); },
                          "parameter 'heads.colour.output_bias' (1 of 3 values) is not finite");
  EXPECT_FALSE(fs::exists(path));
}

// Damage of every kind is refused by eval, render and export (all load through load_trained_avatar), naming what.
TEST(Checkpoint, DamagedFilesAreRefusedByName) {
  TempFolder folder;
  const data::Dataset dataset = six_frame_video(folder);
  train::TrainConfig config = tiny_config();
  config.schedule.iterations = 1;
  const train::RunFolder run{folder / "run"};
  train::train_avatar(dataset, config, run, quiet());
  const std::string good = file_bytes(run.checkpoint_file());
  const train::TrainedAvatar trained = train::load_trained_avatar(run, at::kCPU);
  EXPECT_EQ(trained.iteration, 1);
  EXPECT_TRUE(fs::path(trained.dataset).is_absolute());

  // Where a tensor's bytes lie in the file: found by its first 32 bytes.
  const auto offset_of = [&](const at::Tensor& t) {
    const at::Tensor c = t.contiguous();
    const std::string head(static_cast<const char*>(c.data_ptr()), 32);
    const size_t at = good.find(head);
    EXPECT_NE(at, std::string::npos);
    EXPECT_EQ(good.find(head, at + 1), std::string::npos) << "the pattern must be unique";
    return at;
  };
  const auto named = [&](const std::string& name) {
    for (const auto& p : trained.avatar->named_parameters())
      if (p.key() == name) return p.value();
    for (const auto& b : trained.avatar->named_buffers())
      if (b.key() == name) return b.value();
    ADD_FAILURE() << "no tensor " << name;
    return at::Tensor();
  };
  // One flipped bit in a float parameter: finite, slightly wrong, and caught by its checksum.
  std::string flipped = good;
  flipped[offset_of(named("heads.colour.output_weight")) + 5] ^= 0x10;
  write_bytes(run.checkpoint_file(), flipped);
  expect_error_mentioning([&] { train::load_trained_avatar(run, at::kCPU); },
                          "is damaged: tensor 'heads.colour.output_weight' does not match the checksum");
  // 0xFF bytes over a float tensor (NaN values).
  std::string ones = good;
  const size_t at = offset_of(named("heads.colour.output_weight"));
  for (size_t k = 0; k < 16; ++k) ones[at + k] = char(0xFF);
  write_bytes(run.checkpoint_file(), ones);
  expect_error_mentioning([&] { train::load_trained_avatar(run, at::kCPU); }, "is damaged: tensor 'heads.colour");
  // A flipped bit in an index buffer used to give "index out of range in self".
  std::string faces = good;
  faces[offset_of(named("body.faces")) + 3] ^= 0x40;
  write_bytes(run.checkpoint_file(), faces);
  expect_error_mentioning([&] { train::load_trained_avatar(run, at::kCPU); }, "is damaged: tensor 'body.faces'");
  // Not a checkpoint at all, and one cut short.
  write_bytes(run.checkpoint_file(), "not a checkpoint");
  expect_error_mentioning([&] { train::load_trained_avatar(run, at::kCPU); }, "is not a readable sfgs checkpoint");
  write_bytes(run.checkpoint_file(), good.substr(0, good.size() / 2));
  expect_error_mentioning([&] { train::load_trained_avatar(run, at::kCPU); }, "is not a readable sfgs checkpoint");
  write_bytes(run.checkpoint_file(), good);
  EXPECT_NO_THROW(train::load_trained_avatar(run, at::kCPU));
}

// Resumes that change the model or the data, or ask for an iteration the run has passed, are refused before any
// file of the run is touched.
TEST(TrainerResume, RefusesUnsafeResumesAndRewritesNothing) {
  TempFolder folder;
  const data::Dataset dataset = six_frame_video(folder);
  const train::RunFolder run = paused_run(folder, dataset);
  const std::string checkpoint = file_bytes(run.checkpoint_file()), config = file_bytes(run.config_file()),
                    log = file_bytes(run.log_file());
  train::TrainOptions resume = quiet();
  resume.resume = true;
  train::TrainConfig wider = tiny_config();
  wider.avatar.hidden_width = 2 * wider.avatar.hidden_width;
  wider.avatar.plane_resolution = 2 * wider.avatar.plane_resolution;
  expect_error_mentioning([&] { train::train_avatar(dataset, wider, run, resume); },
                          "keys that change the model, its objective or its data: avatar.plane_resolution (16 -> 32), "
                          "avatar.hidden_width (16 -> 32)");
  const data::Dataset other = six_frame_video(folder, "other", 7);
  expect_error_mentioning([&] { train::train_avatar(other, tiny_config(), run, resume); },
                          "is not the one this run was trained on");
  train::TrainConfig shorter = tiny_config();
  shorter.schedule.iterations = 2;
  expect_error_mentioning([&] { train::train_avatar(dataset, shorter, run, resume); },
                          "it is at iteration 3, past the 2 iterations asked for");
  train::TrainOptions early = resume;
  early.stop_at = 2;
  expect_error_mentioning([&] { train::train_avatar(dataset, tiny_config(), run, early); },
                          "to pause at --stop-at 2: it is already at iteration 3");
  EXPECT_EQ(file_bytes(run.checkpoint_file()), checkpoint);
  EXPECT_EQ(file_bytes(run.config_file()), config);
  EXPECT_EQ(file_bytes(run.log_file()), log);

  // Schedule and logging may change: more iterations, another learning rate.
  train::TrainConfig longer = tiny_config();
  longer.schedule.iterations = 7;
  longer.schedule.learning_rate = 2e-3;
  longer.log_every = 2;
  const train::TrainSummary s = train::train_avatar(dataset, longer, run, resume);
  EXPECT_EQ(s.first_iteration, 3);
  EXPECT_EQ(s.iterations, 7);
  EXPECT_EQ(s.steps, 4);
  EXPECT_TRUE(s.finished);
  // Resuming a finished run does nothing and says so in its summary.
  const std::string finished = file_bytes(run.checkpoint_file());
  const train::TrainSummary again = train::train_avatar(dataset, longer, run, resume);
  EXPECT_EQ(again.steps, 0);
  EXPECT_TRUE(again.finished);
  EXPECT_EQ(file_bytes(run.checkpoint_file()), finished);
}

// A run killed after its checkpoint at 3 had logged steps 4 and 5 (the last half written) and left a temporary:
// the resume drops those rows and the temporary, so each iteration is logged once.
TEST(TrainerResume, RewindsTheLogAndRemovesWhatAKilledRunLeft) {
  TempFolder folder;
  const data::Dataset dataset = six_frame_video(folder);
  const train::RunFolder run = paused_run(folder, dataset);
  {
    std::ofstream log(run.log_file(), std::ios::app);
    log << R"({"event":"step","iteration":4,"loss":{"total":1}})"
        << "\n"
        << R"({"event":"step","iteration":5,"loss":{"total":1}})"
        << "\n"
        << R"({"event":"step","itera)";
  }
  const std::string stale = run.checkpoint_file() + ".tmp-999999999";  // above any pid the kernel hands out
  write_bytes(stale, "half a checkpoint");
  const std::string live = run.path + "/notes.txt.tmp-" + std::to_string(::getpid()) + ".partial";  // a live process's
  write_bytes(live, "in progress");
  train::TrainOptions resume = quiet();
  resume.resume = true;
  train::train_avatar(dataset, tiny_config(), run, resume);
  EXPECT_FALSE(fs::exists(stale));
  EXPECT_TRUE(fs::exists(live));
  std::map<int64_t, int> steps;
  int64_t dropped = -1;
  for (const nlohmann::json& e : log_entries(run)) {
    if (e["event"] == "step") ++steps[e["iteration"].get<int64_t>()];
    if (e["event"] == "resume") dropped = e["dropped_entries"].get<int64_t>();
  }
  EXPECT_EQ(dropped, 3);
  ASSERT_EQ(steps.size(), 6u);
  for (const auto& [iteration, count] : steps) EXPECT_EQ(count, 1) << "iteration " << iteration;
}

TEST(FolderLock, OneHolderPerFolderAndPurposeNamedWhenRefused) {
  TempFolder folder;
  const std::string run = folder / "run";
  {
    const FolderLock train(run, "train");
    const FolderLock eval(run, "eval");  // another purpose: no conflict
    expect_error_mentioning([&] { FolderLock second(run, "train"); },
                            "is in use by another sfgs train (pid " + std::to_string(::getpid()) + ", `");
    // The trainer takes the same lock: a second train into the folder is refused before it writes anything.
    const data::Dataset dataset = six_frame_video(folder);
    expect_error_mentioning([&] { train::train_avatar(dataset, tiny_config(), train::RunFolder{run}, quiet()); },
                            "is in use by another sfgs train");
    EXPECT_FALSE(fs::exists(train::RunFolder{run}.config_file()));
  }
  EXPECT_NO_THROW(FolderLock(run, "train"));  // released with its holder
}

TEST(AtomicFiles, StaleTemporariesOfDeadProcessesAreRemoved) {
  TempFolder folder;
  const std::string dir = folder / "out";
  fs::create_directories(dir);
  write_bytes(dir + "/render.mp4.tmp-999999999.mp4", "x");
  write_bytes(dir + "/frame.png.tmp-999999998", "x");
  write_bytes(dir + "/keep.tmp-" + std::to_string(::getpid()), "x");
  write_bytes(dir + "/notes.tmp-readme", "x");
  fs::create_directories(dir + "/web.tmp-999999997/data");  // a folder write (AtomicFolder)
  write_bytes(dir + "/web.tmp-999999997/data/static.js", "x");
  const std::vector<std::string> removed = remove_stale_temporaries(dir);
  EXPECT_EQ(removed.size(), 3u);
  EXPECT_FALSE(fs::exists(dir + "/web.tmp-999999997"));
  EXPECT_TRUE(fs::exists(dir + "/keep.tmp-" + std::to_string(::getpid())));
  EXPECT_TRUE(fs::exists(dir + "/notes.tmp-readme"));
  EXPECT_FALSE(fs::exists(dir + "/frame.png.tmp-999999998"));
}

TEST(AtomicFiles, AFolderAppearsWholeOrNotAtAll) {
  TempFolder folder;
  const std::string target = folder / "web";
  const auto bytes = [](const std::string& text) { return std::vector<unsigned char>(text.begin(), text.end()); };
  {
    AtomicFolder out(target);
    out.add("data/static.js", bytes("first"));
    EXPECT_FALSE(fs::exists(target));
  }  // given up (an error on the way): nothing stays
  EXPECT_EQ(std::distance(fs::directory_iterator(folder.str()), fs::directory_iterator()), 0);
  AtomicFolder first(target);
  first.add("data/static.js", bytes("first"));
  first.commit(false);
  EXPECT_TRUE(fs::exists(target + "/data/static.js"));
  AtomicFolder second(target);
  second.add("index.html", bytes("second"));
  expect_error_mentioning([&] { second.commit(false); }, "refusing to replace existing '" + target + "'");
  second.commit(true);
  EXPECT_TRUE(fs::exists(target + "/index.html"));
  EXPECT_FALSE(fs::exists(target + "/data/static.js"));  // replaced as a whole, not merged
  EXPECT_EQ(std::distance(fs::directory_iterator(folder.str()), fs::directory_iterator()), 1);
}

// Every queued job runs, on the workers; the first error a job throws reaches the caller (at finish() or its next
// add()), and the jobs after it still run.
TEST(BackgroundJobs, RunsEveryJobAndHandsBackTheFirstError) {
  std::atomic<int> done{0};
  {
    BackgroundJobs jobs(3, 2);
    for (int k = 0; k < 50; ++k) jobs.add([&done] { ++done; });
    jobs.finish();
    EXPECT_EQ(done.load(), 50);
    jobs.add([] { throw std::runtime_error("disk full writing frame 7"); });
    try {
      jobs.finish();
      ADD_FAILURE() << "the job's error was not handed back";
    } catch (const std::runtime_error& e) {
      EXPECT_STREQ(e.what(), "disk full writing frame 7");
    }
    jobs.add([&done] { ++done; });
    jobs.finish();
    EXPECT_EQ(done.load(), 51) << "usable after an error";
    for (int k = 0; k < 10; ++k) jobs.add([&done] { ++done; });
  }  // the destructor runs what is queued
  EXPECT_EQ(done.load(), 61);
  EXPECT_THROW(BackgroundJobs(0, 1), std::invalid_argument);
}

}  // namespace
}  // namespace sfgs::testing
