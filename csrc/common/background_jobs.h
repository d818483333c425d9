#pragma once
// Work the caller need not wait for (files to encode and write) on a few threads of their own: jobs run in any order,
// the queue is bounded (a slow disk holds the caller back instead of filling memory), and the first error a job threw
// comes back to the caller at its next add() or at finish(). Jobs must not share state without their own locking.
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace sfgs {

class BackgroundJobs {
 public:
  // threads >= 1; capacity: queued jobs beyond which add() waits (at least 1).
  BackgroundJobs(int threads, size_t capacity);
  ~BackgroundJobs();  // runs the queued jobs; their errors are dropped then (call finish() to see them)
  BackgroundJobs(const BackgroundJobs&) = delete;
  BackgroundJobs& operator=(const BackgroundJobs&) = delete;

  // Queues a job; waits while the queue is full. Throws the first error a job threw (and queues nothing then).
  void add(std::function<void()> job);
  // Waits for every queued job; throws the first error a job threw.
  void finish();

 private:
  void work();
  void rethrow();
  void stop();  // runs what is queued, then joins the workers

  size_t capacity_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<std::function<void()>> queue_;
  size_t busy_ = 0;
  bool closing_ = false;
  std::exception_ptr error_;
  std::vector<std::thread> workers_;
};

}  // namespace sfgs
