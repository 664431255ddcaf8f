// The viewer's page sessions (view_server.cpp), apart from HTTP so they can be tested alone: per
// client (a page, by its client= id) one incremental Extractor per level of detail, the most
// recent clients kept; the follower that extracts a dragging page's surface at rest in the
// background; and the cancellation between them (a page's own request makes the follower's
// extraction of another surface yield). Internal.
#pragma once
#include <tbb/task_arena.h>

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

#include "adaptiso/extractor.hpp"
#include "adaptiso/prepared_grid.hpp"

namespace adaptiso::detail {

// One incremental Extractor of a page at one level of detail, with its own lock, so a request for
// a coarse level never waits behind a long extraction at a fine one.
struct LevelExtractor {
  std::mutex mutex;
  // Raised by a page's request for this level: the background follower's extraction yields.
  std::atomic<bool> page_waiting{false};
  std::atomic<std::uint64_t> page_requests{0};  // counts them: a follower's job queued before one is stale
  std::unique_ptr<Extractor> extractor;
  double iso = std::numeric_limits<double>::quiet_NaN();  // of the surface it holds
  // What the follower is extracting now (NaN, null: nothing).
  std::atomic<double> following{std::numeric_limits<double>::quiet_NaN()};
  std::atomic<const PreparedGrid*> following_grid{nullptr};
  // The lock for a page's request for the surface at `value` on `grid`: the follower's extraction
  // under way yields at its next stage, unless it is extracting that very surface (at rest the
  // page asks for the drag's last iso-value, which the follower was given): its work is then the
  // page's, and cancelling it to march afresh only threw that work away (on the MR head a rest
  // request took 4.5 s of fresh march after cancelling the follower).
  std::unique_lock<std::mutex> lock_for_page(double value, const PreparedGrid* grid) {
    page_requests.fetch_add(1);
    if (!(following.load() == value && following_grid.load() == grid)) page_waiting.store(true);
    std::unique_lock lock(mutex);
    page_waiting.store(false);
    return lock;
  }
  ExtractStats made;  // of the extraction that made the surface held
  // The surface at iso on grid: extracted unless it already is (the follower's, for one), with the
  // statistics of the extraction that made it. With a cancel flag it may throw ExtractCancelled,
  // leaving no surface (the next call extracts afresh).
  const Mesh& at(const std::shared_ptr<const PreparedGrid>& grid, double value, ExtractStats* stats = nullptr,
                 const std::atomic<bool>* cancel = nullptr) {
    if (!extractor || &extractor->grid() != grid.get()) {
      extractor = std::make_unique<Extractor>(grid);
      iso = std::numeric_limits<double>::quiet_NaN();
    }
    if (value != iso) {
      iso = std::numeric_limits<double>::quiet_NaN();  // until the extraction completes
      made = extractor->extract(value, cancel);
      iso = value;
    }
    if (stats) *stats = made;
    return extractor->mesh();
  }
};

// A page's state: its extractors by level (level 0 is the prepared grid).
struct Client {
  std::mutex mutex;  // guards the vector
  std::vector<std::shared_ptr<LevelExtractor>> levels;
  std::shared_ptr<LevelExtractor> level(std::size_t k) {
    std::lock_guard lock(mutex);
    if (levels.size() <= k) levels.resize(k + 1);
    if (!levels[k]) levels[k] = std::make_shared<LevelExtractor>();
    return levels[k];
  }
};

// While a page drags (coarse surfaces within a budget), its surface at rest follows in the
// background at low priority, the latest iso-value only; so when the slider rests the accurate
// surface is a small step away, not a long one. It uses every core: the coarse requests are small
// (under a millisecond of extraction on the MR head), and on a noisy scan each step of the
// follower is a march of millions of triangles. A page's own request for the level makes the
// follower's extraction yield at its next stage rather than wait for it to finish. (A follower
// alone on a thread at nice 19 was tried: the page's request at rest then waited 7.2 s on the MR
// head for the starved follower to reach a checkpoint and let go of the level.)

// While a page drags (coarse surfaces within a budget), its surface at rest follows in the
// background at low priority, the latest iso-value only; so when the slider rests the accurate
// surface is a small step away, not a long one. It uses every core: the coarse requests are small
// (under a millisecond of extraction on the MR head), and on a noisy scan each step of the
// follower is a march of millions of triangles. A page's own request for the level makes the
// follower's extraction yield at its next stage rather than wait for it to finish. (A follower
// alone on a thread at nice 19 was tried: the page's request at rest then waited 7.2 s on the MR
// head for the starved follower to reach a checkpoint and let go of the level.)
class Follower {
public:
  Follower();
  ~Follower();
  Follower(const Follower&) = delete;
  Follower& operator=(const Follower&) = delete;
  // Extract the surface at iso on grid into slot, in the background; replaces the slot's job not
  // yet started. Dropped when the page asks for the slot's level before it starts.
  void follow(const std::shared_ptr<LevelExtractor>& slot, std::shared_ptr<const PreparedGrid> grid, double iso);
  // Blocks until no job is queued or running (tests).
  void wait_idle();
  // Extractions completed, and yielded to a page's request (tests, diagnostics).
  std::uint64_t completed() const { return completed_.load(); }
  std::uint64_t cancelled() const { return cancelled_.load(); }

private:
  struct Job {
    std::weak_ptr<LevelExtractor> slot;
    std::shared_ptr<const PreparedGrid> grid;
    double iso = 0;
    std::uint64_t page_requests = 0;  // the slot's count when queued
  };
  void run();
  void follow_one(const Job& job);
  tbb::task_arena arena_;
  std::mutex mutex_;
  std::condition_variable ready_, idle_;
  std::unordered_map<const LevelExtractor*, Job> jobs_;
  bool busy_ = false;
  bool stop_ = false;
  std::atomic<std::uint64_t> completed_{0}, cancelled_{0};
  std::thread thread_;
};

// The pages' sessions: clients by id, the least recently used dropped beyond max_clients, and the
// follower. Thread-safe.
class Sessions {
public:
  explicit Sessions(std::size_t max_clients) : max_clients_(max_clients) {}
  // The client's extractor for a level (0: the prepared grid), made on first use; the client
  // becomes the most recent.
  std::shared_ptr<LevelExtractor> slot(const std::string& client, std::size_t level);
  // The client's surface at rest at `level` follows iso on grid in the background.
  void follow(const std::string& client, std::size_t level, std::shared_ptr<const PreparedGrid> grid, double iso);
  // Every client dropped (a new grid: an Extractor keeps its own grid alive).
  void clear();
  std::size_t clients() const;
  bool has(const std::string& client) const;
  Follower& follower() { return follower_; }

private:
  std::shared_ptr<Client> client(const std::string& id);
  std::size_t max_clients_;
  mutable std::mutex mutex_;    // guards the two below
  std::list<std::string> lru_;  // most recent first
  std::unordered_map<std::string, std::pair<std::shared_ptr<Client>, std::list<std::string>::iterator>> clients_;
  Follower follower_;  // last: stopped before the clients go
};

}  // namespace adaptiso::detail
