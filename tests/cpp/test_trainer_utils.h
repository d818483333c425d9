#pragma once
// Shared fixtures of the trainer tests (test_trainer.cpp, test_run_safety.cpp, the pose fitting tests): a tiny
// synthetic video, a config that trains it in seconds, quiet options and the run's log as JSON objects.
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "data/dataset.h"
#include "model/avatar.h"
#include "test_files.h"
#include "train/run_folder.h"
#include "train/trainer.h"

namespace sfgs::testing {

// Six iterations of the small avatar without LPIPS, logging every step, validating every second step on one
// frame, checkpointing only at a pause and at the end.
train::TrainConfig tiny_train_config();

// A synthetic video of `frames` square frames of `side` pixels in folder/name.
data::Dataset tiny_video(const TempFolder& folder, int64_t frames, int64_t side, const std::string& name = "video",
                         uint64_t seed = 1);

// No progress bar.
train::TrainOptions quiet();

// A textured avatar (fixed, random parameters) and the frames `frames` of `dataset` made its own renders of their
// fits: the image, and the mask where the render is opaque. Their fits become the truth (FrameRecord::true_pose).
model::Avatar render_frames_with_avatar(data::Dataset& dataset, const std::vector<int64_t>& frames);

// Every entry of the run's log.jsonl, in order.
std::vector<nlohmann::json> log_entries(const train::RunFolder& run);

}  // namespace sfgs::testing
