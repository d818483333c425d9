#pragma once
// Named stages of an animated frame or a training step, for the benchmarks' per-stage split (bench_animate,
// bench_train_step). Code brackets a stage with a StageScope; it costs one thread-local read unless a StageRecorder
// is installed on the thread, which only benchmarks do (a recorder may synchronise the device to time a stage).
namespace sfgs {

class StageRecorder {
 public:
  virtual void begin(const char* stage) = 0;
  virtual void end(const char* stage) = 0;

 protected:
  ~StageRecorder() = default;
};

// Whether a recorder is installed on this thread (work that must not synchronise, such as the capture of a CUDA
// graph, runs without one).
bool stage_recorder_installed();

// Installs `recorder` on this thread for the scope's lifetime (null installs none).
class ScopedStageRecorder {
 public:
  explicit ScopedStageRecorder(StageRecorder* recorder);
  ~ScopedStageRecorder();
  ScopedStageRecorder(const ScopedStageRecorder&) = delete;
  ScopedStageRecorder& operator=(const ScopedStageRecorder&) = delete;

 private:
  StageRecorder* previous_;
};

// Marks the enclosing scope as the stage `name` (a string literal: recorders keep the pointer).
class StageScope {
 public:
  explicit StageScope(const char* name);
  ~StageScope();
  StageScope(const StageScope&) = delete;
  StageScope& operator=(const StageScope&) = delete;

 private:
  const char* name_;
  StageRecorder* recorder_;
};

}  // namespace sfgs
