#include "common/stage_timer.h"

namespace sfgs {
namespace {
thread_local StageRecorder* installed_recorder = nullptr;
}  // namespace

bool stage_recorder_installed() { return installed_recorder != nullptr; }

ScopedStageRecorder::ScopedStageRecorder(StageRecorder* recorder) : previous_(installed_recorder) {
  installed_recorder = recorder;
}

ScopedStageRecorder::~ScopedStageRecorder() { installed_recorder = previous_; }

StageScope::StageScope(const char* name) : name_(name), recorder_(installed_recorder) {
  if (recorder_ != nullptr) recorder_->begin(name_);
}

StageScope::~StageScope() {
  if (recorder_ != nullptr) recorder_->end(name_);
}

}  // namespace sfgs
