// Internal: the viewer's page sessions, apart from HTTP (issue 40: ~185 lines inside the server
// that could only be tested over HTTP). A client (a page: `client=`) has an incremental Extractor
// per level of detail, so small slider moves are incremental and pages never block each other;
// while a page drags (a coarse level within a triangle budget), a follower extracts the surface at
// rest in the background and yields when the page asks for the level; the levels of detail are
// built from the first request that needs them. All of it is held under a memory budget (issue 41):
// before an extraction the bytes it will hold are reserved; when the resident set would pass the
// budget, idle extractors are dropped, the largest and longest idle first, then idle levels of
// detail; a request that still cannot fit is refused with OverBudget (the server: 503 with
// Retry-After), and what stays idle is dropped after idle_seconds whatever the pressure, so the
// server returns to its baseline when the load stops. Thread-safe throughout.
#pragma once
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "adaptiso/extractor.hpp"
#include "adaptiso/prepare.hpp"

namespace adaptiso::detail {

using Clock = std::chrono::steady_clock;

struct SessionOptions {
  std::size_t max_clients = 32;     // the least recently used clients are dropped beyond this
  std::uint64_t memory_budget = 0;  // bytes of the resident set (resident()); 0: no bound
  // An extractor unused this long is dropped, and the levels of detail unused 5× as long: a page
  // left alone costs nothing, and the next move is one fresh march (0.3 s on the chest CT).
  double idle_seconds = 60;
  bool janitor = true;  // a thread drops what is idle; without it, collect_idle() does (tests)
  // The resident set now, returning freed heap to the system, and the clock: the process's by
  // default; a test gives its own.
  std::function<std::uint64_t()> resident;
  std::function<void()> release_heap;
  std::function<Clock::time_point()> now;
};

// The memory a request needs cannot be had now (the budget is held by requests in flight and
// surfaces in use): retry in a moment.
struct OverBudget : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class Sessions {
public:
  explicit Sessions(SessionOptions options);
  ~Sessions();
  Sessions(const Sessions&) = delete;
  Sessions& operator=(const Sessions&) = delete;

  // The grid to serve (clients, levels and their memory start anew); levels of detail on a
  // bisection grid.
  void set_grid(std::shared_ptr<const PreparedGrid> grid);

  // Memory promised to a request in flight, given back when destroyed.
  class Reservation {
  public:
    Reservation() = default;
    Reservation(Reservation&& o) noexcept;
    Reservation& operator=(Reservation&& o) noexcept;
    ~Reservation();
    std::uint64_t bytes() const { return bytes_; }

  private:
    friend class Sessions;
    struct Impl;
    Reservation(Impl* owner, std::uint64_t bytes) : owner_(owner), bytes_(bytes) {}
    Impl* owner_ = nullptr;
    std::uint64_t bytes_ = 0;
  };

  // A page's surface: the level's Extractor, locked (no other request or the follower changes it)
  // and its memory reserved until destroyed.
  class Surface {
  public:
    Surface(Surface&&) noexcept;
    ~Surface();
    const Extractor& extractor() const;
    const ExtractStats& stats() const { return stats_; }  // of the extraction that made the surface
    std::size_t level() const { return level_; }          // 0: the prepared grid
    const PreparedGrid& grid() const { return *grid_; }
    double wait_seconds() const { return wait_; }  // behind the level's other work (the follower)

  private:
    friend class Sessions;
    struct Lock;
    Surface() = default;
    std::unique_ptr<Lock> lock_;
    std::shared_ptr<const PreparedGrid> grid_;
    ExtractStats stats_;
    std::size_t level_ = 0;
    double wait_ = 0;
  };

  // The surface at iso of a client's page. error= (data units): the coarsest level whose bound is
  // at most it; budget= (triangles): the finest level, no finer than error asks, expected to give
  // at most that many, while the level at rest follows in the background. Throws OverBudget,
  // InputError for a grid the library refuses, std::logic_error before set_grid.
  Surface surface(const std::string& client, double iso, std::optional<double> error, std::optional<double> budget);

  // Memory for a request that holds no Extractor (a distance query, the reference, a wireframe).
  // Throws OverBudget.
  Reservation reserve(std::uint64_t bytes);

  // Surfaces made for a request alone: their triangle counts seen, to foresee their memory.
  enum class Transient { distance, reference };
  // The count expected at iso (from those seen; before any, the prepared grid's surfaces' for a
  // distance query, else `unknown`).
  std::size_t expected_triangles(Transient kind, double iso, std::size_t unknown) const;
  void record_triangles(Transient kind, double iso, std::size_t triangles);

  struct Level {
    double bound;    // data units, guaranteed
    bool built;      // offered
    int cell_floor;  // log2 of the floor's cube side; 0: an error level
  };
  std::vector<Level> levels() const;  // empty without levels of detail

  struct Memory {
    std::uint64_t budget = 0, resident = 0;
    std::uint64_t extractors_bytes = 0;  // estimated
    std::uint64_t reserved = 0;          // for requests in flight
    std::size_t clients = 0, extractors = 0;
    std::size_t levels_built = 0;            // levels of detail held, level 0 included
    std::size_t background = 0;              // the follower's extractions queued or running
    std::uint64_t evicted = 0, refused = 0;  // extractors dropped, requests refused, since the start
  };
  Memory memory() const;
  // The bytes the sessions hold by their own estimate (extractors; memory_budget.hpp): what a
  // test's model of the resident set adds to its baseline. Takes no lock.
  std::uint64_t held_bytes() const;

  // Drops the extractors and levels of detail left idle long enough, and returns freed heap to the
  // system; the janitor thread calls it every second or so.
  void collect_idle();
  // After an allocation failed: drops everything idle at once.
  void relieve();

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace adaptiso::detail
