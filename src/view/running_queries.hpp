// Internal: the distance query each page has running in the viewer. A page asks for a new surface
// while one is still being made only when it no longer wants that one (at most one request in
// flight a page; a drag that resumes overtakes the surface at rest it was waiting for, and the page
// drops that request). Starting a page's query therefore cancels the page's previous one: its flag
// is raised and HierarchyQuery::extract_within stops with ExtractCancelled, instead of holding both
// cores for a surface nobody will draw (0.6 s on the CT bunny at rest, 1.5–2.4 s on the 512×512×120
// MR head). Thread-safe; a ticket forgets its query when destroyed.
#pragma once
#include <atomic>
#include <cstddef>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>

namespace adaptiso::detail {

class RunningQueries {
public:
  // The query of `client` now starting; the client's previous one, still running, is cancelled.
  class Ticket {
  public:
    Ticket(RunningQueries& owner, std::string client)
        : owner_(owner), client_(std::move(client)), flag_(std::make_shared<std::atomic<bool>>(false)) {
      owner_.start(client_, flag_);
    }
    Ticket(const Ticket&) = delete;
    Ticket& operator=(const Ticket&) = delete;
    ~Ticket() { owner_.finish(client_, flag_); }
    const std::atomic<bool>* cancel() const { return flag_.get(); }
    bool cancelled() const { return flag_->load(); }

  private:
    RunningQueries& owner_;
    std::string client_;
    std::shared_ptr<std::atomic<bool>> flag_;
  };

  std::size_t running() const {
    std::lock_guard lock(mutex_);
    return running_.size();
  }

private:
  void start(const std::string& client, const std::shared_ptr<std::atomic<bool>>& flag) {
    std::lock_guard lock(mutex_);
    auto& slot = running_[client];
    if (slot) slot->store(true);
    slot = flag;
  }
  void finish(const std::string& client, const std::shared_ptr<std::atomic<bool>>& flag) {
    std::lock_guard lock(mutex_);
    const auto it = running_.find(client);
    if (it != running_.end() && it->second == flag) running_.erase(it);  // not a newer query's
  }
  mutable std::mutex mutex_;
  std::unordered_map<std::string, std::shared_ptr<std::atomic<bool>>> running_;
};

}  // namespace adaptiso::detail
