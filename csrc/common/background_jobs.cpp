#include "common/background_jobs.h"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <utility>

namespace sfgs {

BackgroundJobs::BackgroundJobs(int threads, size_t capacity) : capacity_(std::max<size_t>(capacity, 1)) {
  if (threads < 1)
    throw std::invalid_argument("BackgroundJobs: threads must be at least 1, got " + std::to_string(threads));
  try {
    for (int k = 0; k < threads; ++k) workers_.emplace_back([this] { work(); });
  } catch (...) {
    stop();  // a thread that could not start: the ones that did stop before the error goes on
    throw;
  }
}

BackgroundJobs::~BackgroundJobs() { stop(); }

void BackgroundJobs::stop() {
  {
    const std::lock_guard<std::mutex> lock(mutex_);
    closing_ = true;
  }
  changed_.notify_all();
  for (std::thread& w : workers_) w.join();
}

void BackgroundJobs::work() {
  for (;;) {
    std::function<void()> job;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [this] { return closing_ || !queue_.empty(); });
      if (queue_.empty()) return;  // closing, and nothing left
      job = std::move(queue_.front());
      queue_.pop_front();
      ++busy_;
    }
    changed_.notify_all();  // room in the queue
    std::exception_ptr failed;
    try {
      job();
    } catch (...) {
      failed = std::current_exception();
    }
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      --busy_;
      if (failed && !error_) error_ = failed;
    }
    changed_.notify_all();
  }
}

void BackgroundJobs::rethrow() {
  if (!error_) return;
  std::exception_ptr error = error_;
  error_ = nullptr;
  std::rethrow_exception(error);
}

void BackgroundJobs::add(std::function<void()> job) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [this] { return error_ || queue_.size() < capacity_; });
  rethrow();
  queue_.push_back(std::move(job));
  lock.unlock();
  changed_.notify_all();
}

void BackgroundJobs::finish() {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [this] { return queue_.empty() && busy_ == 0; });
  rethrow();
}

}  // namespace sfgs
