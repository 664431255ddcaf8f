// The viewer's page sessions (see sessions.hpp).
#include "view/sessions.hpp"

#include <exception>
#include <iostream>

namespace adaptiso::detail {

Follower::Follower() : arena_(tbb::task_arena::automatic, 1, tbb::task_arena::priority::low), thread_([this] { run(); }) {}

Follower::~Follower() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  ready_.notify_all();
  thread_.join();
}

void Follower::follow(const std::shared_ptr<LevelExtractor>& slot, std::shared_ptr<const PreparedGrid> grid, double iso) {
  {
    std::lock_guard lock(mutex_);
    jobs_[slot.get()] = {slot, std::move(grid), iso, slot->page_requests.load()};
  }
  ready_.notify_one();
}

void Follower::wait_idle() {
  std::unique_lock lock(mutex_);
  idle_.wait(lock, [&] { return stop_ || (jobs_.empty() && !busy_); });
}

void Follower::run() {
  for (;;) {
    Job job;
    {
      std::unique_lock lock(mutex_);
      busy_ = false;
      if (jobs_.empty()) idle_.notify_all();
      ready_.wait(lock, [&] { return stop_ || !jobs_.empty(); });
      if (stop_) {
        idle_.notify_all();
        return;
      }
      job = std::move(jobs_.begin()->second);
      jobs_.erase(jobs_.begin());
      busy_ = true;
    }
    follow_one(job);
  }
}

void Follower::follow_one(const Job& job) {
  auto slot = job.slot.lock();
  if (!slot) return;  // the client is gone
  std::lock_guard lock(slot->mutex);
  // The page asked for this level since the job was queued (or is asking now): it has, or is
  // about to get, the surface it wants; following an older iso-value would only move away.
  if (slot->page_requests.load() != job.page_requests) return;
  slot->following_grid.store(job.grid.get());
  slot->following.store(job.iso);
  try {
    arena_.execute([&] { slot->at(job.grid, job.iso, nullptr, &slot->page_waiting); });
    completed_.fetch_add(1);
  } catch (const ExtractCancelled&) {  // the page asked meanwhile: its request extracts
    cancelled_.fetch_add(1);
  } catch (const std::exception& e) {  // the page's own request will meet and report it
    std::cerr << "adaptiso view: background extraction failed: " << e.what() << "\n";
  }
  slot->following.store(std::numeric_limits<double>::quiet_NaN());
  slot->following_grid.store(nullptr);
}

std::shared_ptr<Client> Sessions::client(const std::string& id) {
  std::lock_guard lock(mutex_);
  auto it = clients_.find(id);
  if (it != clients_.end()) {
    lru_.splice(lru_.begin(), lru_, it->second.second);
    return it->second.first;
  }
  while (clients_.size() >= max_clients_ && !lru_.empty()) {
    clients_.erase(lru_.back());
    lru_.pop_back();
  }
  lru_.push_front(id);
  auto c = std::make_shared<Client>();
  clients_[id] = {c, lru_.begin()};
  return c;
}

std::shared_ptr<LevelExtractor> Sessions::slot(const std::string& id, std::size_t level) { return client(id)->level(level); }

void Sessions::follow(const std::string& id, std::size_t level, std::shared_ptr<const PreparedGrid> grid, double iso) {
  follower_.follow(slot(id, level), std::move(grid), iso);
}

void Sessions::clear() {
  std::lock_guard lock(mutex_);
  clients_.clear();
  lru_.clear();
}

std::size_t Sessions::clients() const {
  std::lock_guard lock(mutex_);
  return clients_.size();
}

bool Sessions::has(const std::string& id) const {
  std::lock_guard lock(mutex_);
  return clients_.count(id) > 0;
}

}  // namespace adaptiso::detail
