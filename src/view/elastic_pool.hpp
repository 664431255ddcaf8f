// The viewer's connection threads (view_server.cpp): a task queue for httplib that adds threads
// while all are busy, up to a limit. Internal.
#pragma once
#include <httplib.h>

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace adaptiso::detail {

// Connections are served by threads that are added while all are busy, up to a limit: a few
// clients that send their requests slowly (or hold their connection open) then cannot starve the
// others, as the fixed pool of 8 did (/api/info waited 17 s behind 8 clients sending a header
// line a second).
class ElasticPool : public httplib::TaskQueue {
public:
  explicit ElasticPool(std::size_t max_threads) : max_(max_threads) {}
  void enqueue(std::function<void()> fn) override {
    std::lock_guard lock(mutex_);
    jobs_.push_back(std::move(fn));
    // An idle thread takes one job when it wakes; until then it still counts as idle, so compare
    // the queued jobs with the idle threads (checking idle_ == 0 left a burst of connections
    // queued behind one idle thread, which a slow client then held).
    if (jobs_.size() > idle_ && threads_.size() < max_) threads_.emplace_back([this] { work(); });
    ready_.notify_one();
  }
  void shutdown() override {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    ready_.notify_all();
    for (auto& t : threads_) t.join();
  }

private:
  void work() {
    for (;;) {
      std::function<void()> job;
      {
        std::unique_lock lock(mutex_);
        ++idle_;
        ready_.wait(lock, [&] { return stop_ || !jobs_.empty(); });
        --idle_;
        if (jobs_.empty()) return;  // stopping
        job = std::move(jobs_.front());
        jobs_.pop_front();
      }
      job();
    }
  }
  std::size_t max_;
  std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<std::function<void()>> jobs_;
  std::vector<std::thread> threads_;
  std::size_t idle_ = 0;
  bool stop_ = false;
};

}  // namespace adaptiso::detail
