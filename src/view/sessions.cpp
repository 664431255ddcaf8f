// The viewer's page sessions under a memory budget (see sessions.hpp).
#include "view/sessions.hpp"

#include <fmt/format.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <iostream>
#include <limits>
#include <list>
#include <mutex>
#include <thread>
#include <unordered_map>

#include "adaptiso/levels_of_detail.hpp"
#include "util/memory.hpp"
#include "view/memory_budget.hpp"

namespace adaptiso::detail {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// SurfaceSizes keys of the surfaces made for one request (levels of detail use their index).
constexpr std::size_t kDistanceKey = 1u << 20, kReferenceKey = kDistanceKey + 1;

std::uint64_t saturating_sub(std::uint64_t a, std::uint64_t b) { return a > b ? a - b : 0; }

// One incremental Extractor of a page at one level of detail, with its own lock, so a request for
// a coarse level never waits behind a long extraction at a fine one.
struct Slot {
  explicit Slot(std::shared_ptr<std::atomic<std::uint64_t>> total) : cached_total(std::move(total)) {}
  ~Slot() { cached_total->fetch_sub(bytes.load()); }
  std::mutex mutex;
  // Raised by a page's request for this level: the background follower's extraction yields.
  std::atomic<bool> page_waiting{false};
  std::atomic<std::uint64_t> page_requests{0};  // counts them: a follower's job queued before one is stale
  std::unique_ptr<Extractor> extractor;         // guarded by mutex, like iso and made
  double iso = kNaN;                            // of the surface it holds
  ExtractStats made;                            // of the extraction that made the surface held
  // What the follower is extracting now (NaN, null: nothing).
  std::atomic<double> following{kNaN};
  std::atomic<const PreparedGrid*> following_grid{nullptr};
  // The extractor's memory (estimated, memory_budget.hpp), also counted in *cached_total; written
  // under mutex.
  std::atomic<std::uint64_t> bytes{0};
  std::atomic<Clock::rep> last_used{0};
  std::shared_ptr<std::atomic<std::uint64_t>> cached_total;

  void set_bytes(std::uint64_t b) {
    cached_total->fetch_add(b);
    cached_total->fetch_sub(bytes.exchange(b));
  }
  // Drops the extractor (mutex held); returns the bytes it was estimated to hold.
  std::uint64_t drop() {
    extractor.reset();
    iso = kNaN;
    const std::uint64_t b = bytes.exchange(0);
    cached_total->fetch_sub(b);
    return b;
  }
  bool holds(const PreparedGrid* grid, double value) const { return extractor && &extractor->grid() == grid && iso == value; }

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
  // The surface at iso on grid: extracted unless it already is (the follower's, for one), with the
  // statistics of the extraction that made it. With a cancel flag it may throw ExtractCancelled,
  // leaving no surface (the next call extracts afresh). Any other failure (out of memory) drops
  // the extractor, so the next call starts from a known state.
  const Mesh& at(const std::shared_ptr<const PreparedGrid>& grid, double value, ExtractStats* stats = nullptr,
                 const std::atomic<bool>* cancel = nullptr) {
    if (!extractor || &extractor->grid() != grid.get()) {
      drop();  // before the new one: the two never held at once
      extractor = std::make_unique<Extractor>(grid);
    }
    if (value != iso) {
      iso = kNaN;  // until the extraction completes
      try {
        made = extractor->extract(value, cancel);
      } catch (const ExtractCancelled&) {
        throw;
      } catch (...) {
        drop();
        throw;
      }
      iso = value;
    }
    if (stats) *stats = made;
    return extractor->mesh();
  }
};

// A page's state: its slots by level (level 0 is the prepared grid).
struct Client {
  std::mutex mutex;  // guards the vector
  std::vector<std::shared_ptr<Slot>> levels;
  std::shared_ptr<Slot> level(std::size_t k, const std::shared_ptr<std::atomic<std::uint64_t>>& total) {
    std::lock_guard lock(mutex);
    if (levels.size() <= k) levels.resize(k + 1);
    if (!levels[k]) levels[k] = std::make_shared<Slot>(total);
    return levels[k];
  }
  std::vector<std::pair<std::size_t, std::shared_ptr<Slot>>> holding() {
    std::lock_guard lock(mutex);
    std::vector<std::pair<std::size_t, std::shared_ptr<Slot>>> out;
    for (std::size_t k = 0; k < levels.size(); ++k)
      if (levels[k] && levels[k]->bytes.load() > 0) out.emplace_back(k, levels[k]);
    return out;
  }
};

}  // namespace

struct Sessions::Reservation::Impl {
  std::atomic<std::uint64_t> reserved{0};
};

Sessions::Reservation::Reservation(Reservation&& o) noexcept
    : owner_(std::exchange(o.owner_, nullptr)), bytes_(std::exchange(o.bytes_, 0)) {}
Sessions::Reservation& Sessions::Reservation::operator=(Reservation&& o) noexcept {
  if (this != &o) {
    if (owner_) owner_->reserved.fetch_sub(bytes_);
    owner_ = std::exchange(o.owner_, nullptr);
    bytes_ = std::exchange(o.bytes_, 0);
  }
  return *this;
}
Sessions::Reservation::~Reservation() {
  if (owner_) owner_->reserved.fetch_sub(bytes_);
}

struct Sessions::Surface::Lock {
  std::shared_ptr<Slot> slot;
  std::unique_lock<std::mutex> lock;
  Reservation reservation;
};

Sessions::Surface::Surface(Surface&&) noexcept = default;
Sessions::Surface::~Surface() = default;
const Extractor& Sessions::Surface::extractor() const { return *lock_->slot->extractor; }

namespace {

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
  struct Job {
    std::weak_ptr<Slot> slot;
    std::shared_ptr<const PreparedGrid> grid;
    std::size_t level = 0;
    double iso = 0;
    std::uint64_t page_requests = 0;  // the slot's count when queued
  };
  // Runs a job with the slot locked; false when it was not worth running (or could not fit).
  using Runner = std::function<void(Slot&, const Job&, const std::atomic<bool>* cancel)>;

  explicit Follower(Runner run)
      : run_(std::move(run)), arena_(tbb::task_arena::automatic, 1, tbb::task_arena::priority::low), thread_([this] { loop(); }) {}
  ~Follower() {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    ready_.notify_all();
    thread_.join();
  }
  void follow(const std::shared_ptr<Slot>& slot, std::shared_ptr<const PreparedGrid> grid, std::size_t level, double iso) {
    {
      std::lock_guard lock(mutex_);
      jobs_[slot.get()] = {slot, std::move(grid), level, iso, slot->page_requests.load()};
    }
    ready_.notify_one();
  }
  void clear() {
    std::lock_guard lock(mutex_);
    jobs_.clear();
  }
  // Jobs queued or running (a test waits for none before moving its clock: a job that finishes
  // stamps its level as used).
  std::size_t pending() const {
    std::lock_guard lock(mutex_);
    return jobs_.size() + (running_ ? 1 : 0);
  }

private:
  void loop() {
    for (;;) {
      Job job;
      {
        std::unique_lock lock(mutex_);
        ready_.wait(lock, [&] { return stop_ || !jobs_.empty(); });
        if (stop_) return;
        job = std::move(jobs_.begin()->second);
        jobs_.erase(jobs_.begin());
        running_ = true;
      }
      run_one(job);
      std::lock_guard lock(mutex_);
      running_ = false;
    }
  }
  void run_one(const Job& job) {
    auto slot = job.slot.lock();
    if (!slot) return;  // the client is gone
    std::lock_guard lock(slot->mutex);
    // The page asked for this level since the job was queued (or is asking now): it has, or is
    // about to get, the surface it wants; following an older iso-value would only move away.
    if (slot->page_requests.load() != job.page_requests) return;
    slot->following_grid.store(job.grid.get());
    slot->following.store(job.iso);
    try {
      arena_.execute([&] { run_(*slot, job, &slot->page_waiting); });
    } catch (const ExtractCancelled&) {  // the page asked meanwhile: its request extracts
    } catch (const OverBudget&) {        // no room for background work now: the page's request will ask
    } catch (const std::exception& e) {  // the page's own request will meet and report it
      std::cerr << "adaptiso view: background extraction failed: " << e.what() << "\n";
    }
    slot->following.store(kNaN);
    slot->following_grid.store(nullptr);
  }
  Runner run_;
  tbb::task_arena arena_;
  mutable std::mutex mutex_;
  bool running_ = false;
  std::condition_variable ready_;
  std::unordered_map<const Slot*, Job> jobs_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace

struct Sessions::Impl {
  explicit Impl(SessionOptions o);
  ~Impl();

  SessionOptions opt;
  Clock::time_point now() const { return opt.now(); }
  double seconds_since(Clock::rep ticks) const {
    return std::chrono::duration<double>(now() - Clock::time_point(Clock::duration(ticks))).count();
  }

  // Memory. Admissions are serialised: the resident set is read, room made, bytes promised.
  std::mutex budget_mutex;
  Reservation::Impl promised;  // bytes reserved by requests in flight
  std::shared_ptr<std::atomic<std::uint64_t>> cached = std::make_shared<std::atomic<std::uint64_t>>(0);  // the slots' bytes
  std::atomic<std::uint64_t> evicted{0}, refused{0};
  std::atomic<Clock::rep> last_request{0}, last_trim{0};
  SurfaceSizes sizes;
  Reservation reserve(std::uint64_t bytes, const Slot* self);
  std::uint64_t evict(std::uint64_t deficit, const Slot* self, double min_idle, double levels_min_idle);
  std::uint64_t surface_need(const Slot& slot, const PreparedGrid& grid, std::size_t key, double iso) const;

  mutable std::mutex state_mutex;  // guards everything down to the builder
  std::shared_ptr<const PreparedGrid> grid;
  // Bisection grids: coarser grids for dragging by an error bound, built in the background once a
  // page asks for one (error= or budget=; a page asking for distances never does, and building
  // them took the bunny 22 s of CPU), dropped when unused for 5 idle periods.
  std::shared_ptr<LevelsOfDetail> levels;
  bool building = false;
  Clock::time_point levels_used;
  std::list<std::string> lru;  // most recent first
  std::unordered_map<std::string, std::pair<std::shared_ptr<Client>, std::list<std::string>::iterator>> clients;
  std::shared_ptr<Client> client(const std::string& id);
  std::vector<std::shared_ptr<Slot>> slots_holding(const Slot* except) const;

  std::mutex builder_mutex;  // guards builder
  std::thread builder;
  std::atomic<bool> stop_building{false};
  void need_levels();
  void stop_builder();
  std::uint64_t drop_levels(double min_idle);

  std::unique_ptr<Follower> follower;
  void follow(Slot& slot, const Follower::Job& job, const std::atomic<bool>* cancel);

  std::mutex janitor_mutex;
  std::condition_variable janitor_wake;
  bool janitor_stop = false;
  std::thread janitor;
};

Sessions::Impl::Impl(SessionOptions o) : opt(std::move(o)) {
  if (!opt.resident) opt.resident = resident_bytes;
  if (!opt.release_heap) opt.release_heap = release_free_heap;
  if (!opt.now) opt.now = [] { return Clock::now(); };
  follower = std::make_unique<Follower>([this](Slot& s, const Follower::Job& j, const std::atomic<bool>* c) { follow(s, j, c); });
}

Sessions::Impl::~Impl() {
  {
    std::lock_guard lock(janitor_mutex);
    janitor_stop = true;
  }
  janitor_wake.notify_all();
  if (janitor.joinable()) janitor.join();
  follower.reset();
  stop_builder();
}

Sessions::Sessions(SessionOptions options) : impl_(std::make_unique<Impl>(std::move(options))) {
  if (!impl_->opt.janitor) return;
  // Every second, or 4 times an idle period when that is shorter (tests).
  const auto period = std::chrono::duration<double>(std::clamp(impl_->opt.idle_seconds / 4, 0.02, 1.0));
  impl_->janitor = std::thread([this, period] {
    std::unique_lock lock(impl_->janitor_mutex);
    while (!impl_->janitor_wake.wait_for(lock, period, [&] { return impl_->janitor_stop; })) {
      lock.unlock();
      collect_idle();
      lock.lock();
    }
  });
}

Sessions::~Sessions() = default;

std::shared_ptr<Client> Sessions::Impl::client(const std::string& id) {
  std::lock_guard lock(state_mutex);
  auto it = clients.find(id);
  if (it != clients.end()) {
    lru.splice(lru.begin(), lru, it->second.second);
    return it->second.first;
  }
  while (clients.size() >= opt.max_clients && !lru.empty()) {
    clients.erase(lru.back());
    lru.pop_back();
  }
  lru.push_front(id);
  auto c = std::make_shared<Client>();
  clients[id] = {c, lru.begin()};
  return c;
}

std::vector<std::shared_ptr<Slot>> Sessions::Impl::slots_holding(const Slot* except) const {
  std::vector<std::shared_ptr<Slot>> out;
  std::lock_guard lock(state_mutex);
  for (const auto& [id, entry] : clients)
    for (auto& [level, slot] : entry.first->holding())
      if (slot.get() != except) out.push_back(std::move(slot));
  return out;
}

// Extractors unused for min_idle go first, scored by size × idle time (+1 s, so size decides among
// those just used): a large one long unused costs most to keep, a small one in steady use least.
// Those locked (being extracted or sent) stay. Then the levels of detail, when unused for
// levels_min_idle.
std::uint64_t Sessions::Impl::evict(std::uint64_t deficit, const Slot* self, double min_idle, double levels_min_idle) {
  struct Candidate {
    std::shared_ptr<Slot> slot;
    double score;
  };
  std::vector<Candidate> candidates;
  for (auto& s : slots_holding(self)) {
    const double idle = seconds_since(s->last_used.load());
    if (idle >= min_idle) candidates.push_back({s, static_cast<double>(s->bytes.load()) * (std::max(idle, 0.0) + 1)});
  }
  std::sort(candidates.begin(), candidates.end(), [](const auto& a, const auto& b) { return a.score > b.score; });
  std::uint64_t freed = 0;
  for (auto& c : candidates) {
    if (freed >= deficit) break;
    std::unique_lock lock(c.slot->mutex, std::try_to_lock);
    if (!lock) continue;
    freed += c.slot->drop();
    evicted.fetch_add(1);
  }
  if (freed < deficit) freed += drop_levels(levels_min_idle);
  return freed;
}

// Drops the levels of detail (the ladder is one piece: built together, shared by every page) when
// unused for min_idle, with the idle extractors on them; a later request builds them again.
std::uint64_t Sessions::Impl::drop_levels(double min_idle) {
  std::shared_ptr<LevelsOfDetail> old;
  {
    std::lock_guard lock(state_mutex);
    if (!levels || building || levels->built() <= 1) return 0;
    if (std::chrono::duration<double>(now() - levels_used).count() < min_idle) return 0;
    old = std::move(levels);
    levels = std::make_shared<LevelsOfDetail>(grid);
  }
  std::uint64_t freed = 0;
  for (std::size_t k = 1; k < old->size(); ++k)
    if (const auto g = old->grid(k)) freed += grid_bytes(*g);
  std::vector<std::shared_ptr<Slot>> on_levels;
  {
    std::lock_guard lock(state_mutex);
    for (const auto& [id, entry] : clients)
      for (auto& [level, slot] : entry.first->holding())
        if (level > 0) on_levels.push_back(std::move(slot));
  }
  for (auto& s : on_levels) {
    std::unique_lock lock(s->mutex, std::try_to_lock);
    if (!lock) continue;  // in use: it keeps its grid alive until its page moves on
    freed += s->drop();
    evicted.fetch_add(1);
  }
  return freed;
}

// Reserves `bytes` when the resident set, the bytes promised to requests in flight and these fit
// the budget; else makes room (idle extractors, idle levels, the heap's free pages) and measures
// again. What is in use cannot go: then the request is refused, unless nothing else holds memory
// (the budget is smaller than one surface: refusing would refuse everything, always).
Sessions::Reservation Sessions::Impl::reserve(std::uint64_t bytes, const Slot* self) {
  const std::uint64_t budget = opt.memory_budget;
  if (budget == 0) {
    promised.reserved.fetch_add(bytes);
    return Reservation(&promised, bytes);
  }
  std::lock_guard lock(budget_mutex);
  std::uint64_t resident = opt.resident();
  bool trimmed = false;
  for (;;) {
    const std::uint64_t want = resident + promised.reserved.load() + bytes;
    if (want <= budget) break;
    // Under pressure the levels go once unused for an idle period: while pages drag they are
    // in use, and dropping them then would only have them built again at once.
    const std::uint64_t freed = evict(want - budget, self, 0, opt.idle_seconds);
    if (freed == 0 && trimmed) {
      const std::uint64_t own = self ? self->bytes.load() : 0;
      if (promised.reserved.load() == 0 && cached->load() <= own) break;
      refused.fetch_add(1);
      throw OverBudget(
          fmt::format("the viewer's memory budget ({}) is taken by requests in flight and surfaces in use: "
                      "retry in a moment (or start it with a larger --memory-budget)",
                      byte_size_text(budget)));
    }
    opt.release_heap();
    last_trim.store(now().time_since_epoch().count());
    trimmed = true;
    resident = opt.resident();
  }
  promised.reserved.fetch_add(bytes);
  return Reservation(&promised, bytes);
}

// What an extraction on `grid` will add: a new extractor's sweep state, the triangles it is
// expected to have beyond those it holds, and the answer's bytes.
std::uint64_t Sessions::Impl::surface_need(const Slot& slot, const PreparedGrid& g, std::size_t key, double iso) const {
  const bool fresh = !slot.extractor || &slot.extractor->grid() != &g;
  const std::uint64_t expected = sizes.expected(key, iso, g.grid.tet_count() / 8);
  const std::uint64_t held = fresh ? 0 : slot.extractor->mesh().triangle_count();
  return (fresh ? extractor_fixed_bytes(g) : 0) + kExtractorBytesPerTriangle * saturating_sub(expected, held) +
         kAnswerBytesPerTriangle * expected;
}

void Sessions::Impl::follow(Slot& slot, const Follower::Job& job, const std::atomic<bool>* cancel) {
  if (slot.holds(job.grid.get(), job.iso)) return;
  const Reservation room = reserve(surface_need(slot, *job.grid, job.level, job.iso), &slot);
  ExtractStats st;
  slot.at(job.grid, job.iso, &st, cancel);
  slot.set_bytes(extractor_bytes(*job.grid, slot.extractor->mesh().triangle_count()));
  slot.last_used.store(now().time_since_epoch().count());
  sizes.record(job.level, job.iso, st.triangles);
}

// The levels of detail are built from the first request that needs them, with room reserved for
// the largest (no larger than the prepared grid); without room they are not offered for now
// (requests use the levels built, or the prepared grid) and the next request tries again.
void Sessions::Impl::need_levels() {
  std::shared_ptr<LevelsOfDetail> lod;
  {
    std::lock_guard lock(state_mutex);
    levels_used = now();
    if (!levels || building || levels->built() == levels->size()) return;
    lod = levels;
    building = true;
  }
  Reservation room;
  try {
    room = reserve(grid_bytes(*lod->grid(0)), nullptr);
  } catch (const OverBudget&) {
    std::lock_guard lock(state_mutex);
    building = false;
    return;
  }
  std::lock_guard lock(builder_mutex);
  if (builder.joinable()) builder.join();  // the last build, finished (building was false)
  stop_building = false;
  builder = std::thread([this, lod, room = std::move(room)]() mutable {
    try {
      lod->build(&stop_building);
    } catch (const std::exception& e) {  // out of memory, most likely: the page keeps the levels it has
      std::cerr << "adaptiso view: levels of detail stopped: " << e.what() << "\n";
    }
    room = Reservation();
    std::lock_guard lock(state_mutex);
    building = false;
  });
}

void Sessions::Impl::stop_builder() {
  std::lock_guard lock(builder_mutex);
  stop_building = true;
  if (builder.joinable()) builder.join();
  stop_building = false;
}

void Sessions::set_grid(std::shared_ptr<const PreparedGrid> g) {
  auto lod = g && g->hierarchy ? std::make_shared<LevelsOfDetail>(g) : nullptr;
  impl_->stop_builder();  // the last grid's
  impl_->follower->clear();
  std::unordered_map<std::string, std::pair<std::shared_ptr<Client>, std::list<std::string>::iterator>> old;
  {
    std::lock_guard lock(impl_->state_mutex);
    old.swap(impl_->clients);  // a client's Extractor keeps its own grid alive; new requests start on this one
    impl_->lru.clear();
    impl_->levels = std::move(lod);
    impl_->building = false;
    if (g) impl_->sizes.reset(g->grid.source.min, g->grid.source.max);
    impl_->grid = std::move(g);
  }
  old.clear();  // outside the lock: destroying extractors takes a while
  impl_->opt.release_heap();
}

Sessions::Surface Sessions::surface(const std::string& id, double iso, std::optional<double> error, std::optional<double> budget) {
  Impl& m = *impl_;
  std::shared_ptr<const PreparedGrid> g0;
  std::shared_ptr<LevelsOfDetail> lod;
  {
    std::lock_guard lock(m.state_mutex);
    if (!m.grid) throw std::logic_error("Sessions::surface before set_grid");
    g0 = m.grid;
    lod = m.levels;
  }
  m.last_request.store(m.now().time_since_epoch().count());
  if (lod && (error || budget)) {
    m.need_levels();
    std::lock_guard lock(m.state_mutex);
    lod = m.levels;  // the same ladder, unless it was dropped meanwhile (then a new one, being built)
  }
  // The level shown when the slider rests: the coarsest within error=; while dragging, as fine as
  // the triangle budget allows but no finer.
  const std::size_t rest = lod && error ? lod->level_for_error(*error) : 0;
  const std::size_t level = lod && budget ? lod->level_for_budget(static_cast<std::size_t>(std::min(*budget, 4e9)), rest, iso) : rest;
  auto at = [&](std::size_t k) { return k ? lod->grid(k) : g0; };
  const auto grid = at(level);
  auto c = m.client(id);
  auto slot = c->level(level, m.cached);
  const auto queued = Clock::now();
  Surface s;
  // One extraction at a time per page and level; others run freely. The follower yields to this
  // request (or finishes, when it is extracting this very surface), and its jobs for the level
  // queued before it are dropped.
  s.lock_ = std::make_unique<Surface::Lock>(Surface::Lock{slot, slot->lock_for_page(iso, grid.get()), {}});
  // Time spent behind this level's other work (the follower's current stage, or its extraction of
  // this surface), reported apart.
  s.wait_ = std::chrono::duration<double>(Clock::now() - queued).count();
  s.lock_->reservation = slot->holds(grid.get(), iso) ? m.reserve(kAnswerBytesPerTriangle * slot->made.triangles, slot.get())
                                                      : m.reserve(m.surface_need(*slot, *grid, level, iso), slot.get());
  slot->at(grid, iso, &s.stats_);
  slot->set_bytes(extractor_bytes(*grid, slot->extractor->mesh().triangle_count()));
  slot->last_used.store(m.now().time_since_epoch().count());
  m.sizes.record(level, iso, s.stats_.triangles);
  if (lod) lod->record(level, s.stats_.triangles, iso);
  if (level != rest) m.follower->follow(c->level(rest, m.cached), at(rest), rest, iso);
  s.grid_ = grid;
  s.level_ = level;
  return s;
}

Sessions::Reservation Sessions::reserve(std::uint64_t bytes) {
  impl_->last_request.store(impl_->now().time_since_epoch().count());
  return impl_->reserve(bytes, nullptr);
}

std::size_t Sessions::expected_triangles(Transient kind, double iso, std::size_t unknown) const {
  if (kind == Transient::reference) return impl_->sizes.expected(kReferenceKey, iso, unknown);
  return impl_->sizes.expected(kDistanceKey, iso, impl_->sizes.expected(0, iso, unknown));
}

void Sessions::record_triangles(Transient kind, double iso, std::size_t triangles) {
  impl_->sizes.record(kind == Transient::reference ? kReferenceKey : kDistanceKey, iso, triangles);
}

std::vector<Sessions::Level> Sessions::levels() const {
  std::shared_ptr<LevelsOfDetail> lod;
  {
    std::lock_guard lock(impl_->state_mutex);
    lod = impl_->levels;
  }
  std::vector<Level> out;
  if (lod)
    for (std::size_t k = 0; k < lod->size(); ++k) out.push_back({lod->bound(k), lod->grid(k) != nullptr, lod->cell_floor(k)});
  return out;
}

Sessions::Memory Sessions::memory() const {
  Memory m;
  m.budget = impl_->opt.memory_budget;
  m.background = impl_->follower->pending();
  m.resident = impl_->opt.resident();
  m.extractors_bytes = impl_->cached->load();
  m.reserved = impl_->promised.reserved.load();
  m.evicted = impl_->evicted.load();
  m.refused = impl_->refused.load();
  m.extractors = impl_->slots_holding(nullptr).size();
  std::lock_guard lock(impl_->state_mutex);
  m.clients = impl_->clients.size();
  m.levels_built = impl_->levels ? impl_->levels->built() : impl_->grid ? 1 : 0;
  return m;
}

std::uint64_t Sessions::held_bytes() const { return impl_->cached->load(); }

void Sessions::collect_idle() {
  Impl& m = *impl_;
  const double idle = m.opt.idle_seconds;
  // The levels are kept 5× as long as an extractor: building them again takes a while (the
  // chest CT: 9 s of CPU), an extractor one fresh march.
  const std::uint64_t freed = m.evict(std::numeric_limits<std::uint64_t>::max(), nullptr, idle, 5 * idle);
  {
    std::lock_guard lock(m.state_mutex);
    for (auto it = m.clients.begin(); it != m.clients.end();) {  // clients holding nothing, idle
      const auto& c = it->second.first;
      bool quiet = c->holding().empty();
      {
        std::lock_guard cl(c->mutex);
        for (const auto& s : c->levels) quiet = quiet && (!s || m.seconds_since(s->last_used.load()) >= idle);
      }
      if (quiet) {
        m.lru.erase(it->second.second);
        it = m.clients.erase(it);
      } else {
        ++it;
      }
    }
    // Levels being built while the resident set is past the budget: stop at the next level (the
    // built ones stay offered; a later request resumes when there is room).
    if (m.building && m.opt.memory_budget && m.opt.resident() > m.opt.memory_budget) m.stop_building = true;
  }
  // The heap's free pages back to the system once things were dropped, or once the requests stop
  // (their answers and scratch were freed into the heap, where they stay resident otherwise).
  const Clock::rep last = m.last_request.load(), trimmed = m.last_trim.load();
  if (freed > 0 || (trimmed < last && m.seconds_since(last) >= std::min(idle, 1.0))) {
    m.opt.release_heap();
    m.last_trim.store(m.now().time_since_epoch().count());
  }
}

void Sessions::relieve() {
  impl_->evict(std::numeric_limits<std::uint64_t>::max(), nullptr, 0, impl_->opt.idle_seconds);
  impl_->opt.release_heap();
}

}  // namespace adaptiso::detail
