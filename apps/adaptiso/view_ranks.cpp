// Surfaces within a distance made by other ranks while rank 0 serves the viewer (view_ranks.hpp).
//
// Messages between rank 0 and rank r (r ≥ 1), tagged:
//   ask    0 → r  {id, iso, distance, rounds}
//   cancel 0 → r  {id}: the page no longer wants that surface (a drag overtook it)
//   answer r → 0  {id, status, then the statistics and the mesh's arrays, or a message}
//   stop   0 → r  {}
// Every side polls (MPI_Iprobe, then a short sleep) instead of waiting in a blocking receive:
// OpenMPI's blocking calls spin, so an idle viewer's ranks would each keep a core busy, the core a
// workstation's browser draws with. The sleeps add a fraction of a millisecond to a surface while
// the page asks for them one after another, up to 8 ms to the first after a pause.
#include "view_ranks.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <mutex>
#include <new>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <type_traits>
#include <vector>

#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"

namespace adaptiso::cli {
namespace {

constexpr int kAsk = 20, kCancel = 21, kAnswer = 22, kStop = 23;
// Rank 0, waiting for an answer: polling every 0.2 ms took 8-11 % of a core during a 2.6 s query.
constexpr auto kWaitPoll = std::chrono::milliseconds(1);
constexpr auto kBusyPoll = std::chrono::milliseconds(1);  // the others, listening for a cancel
// The others waiting for work: every 0.25 ms for a second after their last answer (a drag asks
// again within 50-150 ms: a longer sleep is latency on every surface), then doubled while none
// comes, up to 8 ms (an idle rank polling every millisecond took 3.8 % of a core: OpenMPI's
// progress in each probe).
constexpr auto kFirstIdlePoll = std::chrono::microseconds(250), kLongestIdlePoll = std::chrono::microseconds(8000);
constexpr auto kStayAwake = std::chrono::seconds(1);

enum class Status : std::uint8_t { made, cancelled, input_error, out_of_memory, failed };

static_assert(std::is_trivially_copyable_v<DistanceQueryStats>, "sent as its bytes (every rank runs the same program)");

struct Ask {
  std::uint64_t id;
  double iso, distance;
  std::int32_t rounds;
  std::optional<double> min_piece;
};

class Bytes {
public:
  template <class T>
  void put(const T& x) {
    static_assert(std::is_trivially_copyable_v<T>);
    put_raw(&x, sizeof x);
  }
  template <class T>
  void put_array(const std::vector<T>& v) {
    put(static_cast<std::uint64_t>(v.size()));
    put_raw(v.data(), v.size() * sizeof(T));
  }
  void put_raw(const void* p, std::size_t n) {
    const auto* b = static_cast<const std::byte*>(p);
    bytes.insert(bytes.end(), b, b + n);
  }
  std::vector<std::byte> bytes;
};

// Reads what Bytes wrote; a short message is a bug on the other side, not the user's input.
class Reader {
public:
  explicit Reader(const std::vector<std::byte>& b) : b_(b) {}
  template <class T>
  T get() {
    T x;
    get_raw(&x, sizeof x);
    return x;
  }
  template <class T>
  void get_array(std::vector<T>& v) {
    const auto n = get<std::uint64_t>();
    if (n > (b_.size() - at_) / sizeof(T)) throw std::runtime_error("a rank's answer was cut short");
    v.resize(n);
    get_raw(v.data(), n * sizeof(T));
  }
  std::string rest() const { return {reinterpret_cast<const char*>(b_.data()) + at_, b_.size() - at_}; }

private:
  void get_raw(void* p, std::size_t n) {
    if (n > b_.size() - at_) throw std::runtime_error("a rank's answer was cut short");
    std::memcpy(p, b_.data() + at_, n);
    at_ += n;
  }
  const std::vector<std::byte>& b_;
  std::size_t at_ = 0;
};

// The answer to one ask, made on this rank.
std::vector<std::byte> answer(const HierarchyQuery& query, const Ask& ask, const std::atomic<bool>& cancel) {
  Bytes out;
  auto failed = [&](Status s, const std::string& message) {
    out.bytes.clear();
    out.put(ask.id);
    out.put(s);
    out.put_raw(message.data(), message.size());
  };
  try {
    DistanceQueryStats stats;
    const Mesh mesh = query.extract_within(ask.iso, ask.distance, &stats, ask.rounds, &cancel, {}, ask.min_piece);
    // Written once, in place: the rank holds the mesh and its message, no third copy.
    out.bytes.reserve(sizeof ask.id + 1 + sizeof stats + 3 * 8 +
                      12 * (mesh.positions.size() + mesh.normals.size() + mesh.triangles.size()));
    out.put(ask.id);
    out.put(Status::made);
    out.put(stats);
    out.put_array(mesh.positions);
    out.put_array(mesh.normals);
    out.put_array(mesh.triangles);
  } catch (const ExtractCancelled&) {
    failed(Status::cancelled, "");
  } catch (const InputError& e) {  // OptionError too
    failed(Status::input_error, e.what());
  } catch (const std::bad_alloc&) {
    failed(Status::out_of_memory, "");
  } catch (const std::exception& e) {
    failed(Status::failed, e.what());
  }
  return std::move(out.bytes);
}

}  // namespace

struct RankSurfaces::State {
  Ranks& ranks;
  std::mutex mpi;  // one MPI call at a time (MPI_THREAD_SERIALIZED)
  std::mutex idle_mutex;
  std::vector<bool> busy;  // by rank; rank 0 is never handed work here
  std::uint64_t next_id = 1;

  explicit State(Ranks& r) : ranks(r), busy(static_cast<std::size_t>(r.size()), false) { busy[0] = true; }

  // The lowest idle rank, now busy, and the ask's id; rank 0 when every other one is busy.
  std::pair<int, std::uint64_t> take() {
    std::lock_guard lock(idle_mutex);
    for (std::size_t r = 1; r < busy.size(); ++r)
      if (!busy[r]) {
        busy[r] = true;
        return {static_cast<int>(r), next_id++};
      }
    return {0, 0};
  }
  void give_back(int rank) {
    std::lock_guard lock(idle_mutex);
    busy[static_cast<std::size_t>(rank)] = false;
  }

  Mesh make(const HierarchyQuery& local, double iso, double distance, int rounds, std::optional<double> min_piece,
            DistanceQueryStats* stats, const std::atomic<bool>* cancel, int* process) {
    const auto [rank, id] = take();
    *process = rank;
    if (rank == 0) return local.extract_within(iso, distance, stats, rounds, cancel, {}, min_piece);
    struct GiveBack {
      State& s;
      int rank;
      ~GiveBack() { s.give_back(rank); }
    } give_back_on_exit{*this, rank};
    Bytes ask;  // field by field: the struct's padding is not sent
    ask.put(id), ask.put(iso), ask.put(distance), ask.put(static_cast<std::int32_t>(rounds));
    ask.put(static_cast<std::uint8_t>(min_piece.has_value())), ask.put(min_piece.value_or(0.0));
    {
      std::lock_guard lock(mpi);
      ranks.send_message(rank, kAsk, ask.bytes);
    }
    std::vector<std::byte> got;
    for (bool told = false;;) {
      {
        std::lock_guard lock(mpi);
        // An older ask's answer, left by a wait that ended without it (an allocation that failed
        // while receiving it), is dropped: taken for this one's, every later answer of the rank
        // would be one behind.
        if (ranks.poll_message(rank, kAnswer, got) == kAnswer && answer_id(got) == id) break;
        if (!told && cancel && cancel->load(std::memory_order_relaxed)) {
          Bytes c;
          c.put(id);
          ranks.send_message(rank, kCancel, c.bytes);
          told = true;
        }
      }
      std::this_thread::sleep_for(kWaitPoll);
    }
    return read_answer(got, rank, stats);
  }

  static std::uint64_t answer_id(const std::vector<std::byte>& got) {
    std::uint64_t id = 0;
    if (got.size() >= sizeof id) std::memcpy(&id, got.data(), sizeof id);
    return id;
  }

  static Mesh read_answer(const std::vector<std::byte>& got, int rank, DistanceQueryStats* stats) {
    Reader in(got);
    in.get<std::uint64_t>();  // the id, matched
    switch (in.get<Status>()) {
      case Status::made: {
        const auto st = in.get<DistanceQueryStats>();
        if (stats) *stats = st;
        Mesh mesh;
        in.get_array(mesh.positions);
        in.get_array(mesh.normals);
        in.get_array(mesh.triangles);
        return mesh;
      }
      case Status::cancelled:
        throw ExtractCancelled();
      case Status::input_error:
        throw InputError(in.rest());
      case Status::out_of_memory:
        throw std::bad_alloc();
      default:
        throw std::runtime_error(fmt::format("rank {}: {}", rank, in.rest()));
    }
  }
};

RankSurfaces::RankSurfaces(Ranks& ranks) : state_(std::make_shared<State>(ranks)) {}

RankSurfaces::~RankSurfaces() {
  std::lock_guard lock(state_->mpi);
  for (int r = 1; r < state_->ranks.size(); ++r) state_->ranks.send_message(r, kStop, {});
}

DistanceSurfaces RankSurfaces::hook() {
  return [s = state_](const HierarchyQuery& local, double iso, double distance, int rounds, std::optional<double> min_piece,
                      DistanceQueryStats* stats, const std::atomic<bool>* cancel,
                      int* process) { return s->make(local, iso, distance, rounds, min_piece, stats, cancel, process); };
}

void answer_distance_queries(Ranks& ranks, const HierarchyQuery& query) {
  std::vector<std::byte> got;
  auto last_answer = std::chrono::steady_clock::now();
  for (auto idle = kFirstIdlePoll;;) {
    const int tag = ranks.poll_message(0, -1, got);
    if (tag < 0) {
      std::this_thread::sleep_for(idle);
      if (std::chrono::steady_clock::now() - last_answer > kStayAwake) idle = std::min(2 * idle, kLongestIdlePoll);
      continue;
    }
    idle = kFirstIdlePoll;
    if (tag == kStop) return;
    if (tag != kAsk) continue;  // a cancel of an ask answered already
    Reader in(got);
    Ask ask;
    ask.id = in.get<std::uint64_t>(), ask.iso = in.get<double>(), ask.distance = in.get<double>(), ask.rounds = in.get<std::int32_t>();
    const bool own_piece = in.get<std::uint8_t>() != 0;
    const double piece = in.get<double>();
    if (own_piece) ask.min_piece = piece;
    std::atomic<bool> cancel{false}, done{false};
    std::vector<std::byte> reply;
    // The query runs beside this thread, which alone speaks MPI and listens for its cancel.
    std::thread worker([&] {
      reply = answer(query, ask, cancel);
      done.store(true, std::memory_order_release);
    });
    while (!done.load(std::memory_order_acquire)) {
      std::uint64_t id = 0;
      if (ranks.poll_message(0, kCancel, got) == kCancel && got.size() == sizeof id &&
          (std::memcpy(&id, got.data(), sizeof id), id == ask.id))
        cancel.store(true, std::memory_order_relaxed);
      else
        std::this_thread::sleep_for(kBusyPoll);
    }
    worker.join();
    ranks.send_message(0, kAnswer, reply);
    last_answer = std::chrono::steady_clock::now();
  }
}

}  // namespace adaptiso::cli
