// Preparation straight into a grid file (see prepare_to_file.hpp): prepare()'s steps before the
// index (prepare.hpp), then the grid file without its index, which loading builds (grid_file.hpp:
// faster than checking a stored one). A bisection grid's tetrahedra go into the file as the
// selection makes them, a piece at a time: no process holds them all (the CT bunny's 0.87 GB).
#include "adaptiso/prepare_to_file.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <chrono>
#include <utility>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/grid_file.hpp"
#include "index/tet_range.hpp"
#include "io/grid_file_stream.hpp"

namespace adaptiso {
namespace {

using Clock = std::chrono::steady_clock;

// The file's sink: the head and vertices, then each piece of tetrahedra, counting what the index
// loading builds will hold (for the statistics: its depth and size).
class FileSink final : public detail::PreparedGridSink {
public:
  explicit FileSink(std::ostream& out) : stream_(out) {}
  void begin(const PrepareStats& stats, const TetGrid& vertices, const BisectionHierarchy& hierarchy) override {
    stream_.head(stats, vertices, hierarchy);
    values_ = vertices.values.data();
    tets_ = stats.tetrahedra;
    stride_ = interval_tree_sample_stride(tets_);
  }
  void write(std::span<const std::array<std::uint32_t, 4>> tets) override {
    count(tets);
    stream_.tetrahedra(tets);
  }
  void finish(const BisectionHierarchy& hierarchy) { stream_.finish(hierarchy); }
  IntervalTreeShape shape(std::uint32_t depth) const { return interval_tree_shape(tets_, entries_, sampled_, depth); }

private:
  // The non-constant tetrahedra, as the index's build and interval_tree_shape count them (tet_range).
  void count(std::span<const std::array<std::uint32_t, 4>> tets) {
    using Counts = std::pair<std::uint64_t, std::uint64_t>;
    const Counts c = tbb::parallel_reduce(
        tbb::blocked_range<std::size_t>(0, tets.size(), 1 << 16), Counts{0, 0},
        [&](const auto& r, Counts n) {
          for (std::size_t i = r.begin(); i < r.end(); ++i) {
            if (const detail::Range q = detail::tet_range(values_, tets[i]); q.lo < q.hi) {
              ++n.first;
              n.second += (next_ + i) % stride_ == 0;
            }
          }
          return n;
        },
        [](Counts a, Counts b) {
          return Counts{a.first + b.first, a.second + b.second};
        });
    entries_ += c.first;
    sampled_ += c.second;
    next_ += tets.size();
  }

  detail::GridFileStream stream_;
  const double* values_ = nullptr;
  std::uint64_t tets_ = 0, next_ = 0, entries_ = 0, sampled_ = 0;
  std::size_t stride_ = 1;
};

// The stage "save" lengthened by what followed the last tetrahedra (the hierarchy, the rename).
void add_to_save(PrepareStats& stats, double seconds) {
  for (auto& s : stats.stages)
    if (s.name == "save") s.seconds += seconds;
}

PrepareStats prepare_sunk(const Volume& v, const ValueRange& range, const PrepareOptions& o, const std::string& path,
                          const Progress& progress, Volume* release) {
  PreparedGrid p;
  IntervalTreeShape shape;
  Clock::time_point t0;
  write_file_atomically(path, [&](std::ostream& out) {
    FileSink sink(out);
    p = detail::prepare_unindexed(v, range, o, progress, release, &sink);
    t0 = Clock::now();
    report(progress, "save", 0);
    sink.finish(*p.hierarchy);
    shape = sink.shape(o.tree_depth);
  });
  report(progress, "save", 1);
  add_to_save(p.stats, std::chrono::duration<double>(Clock::now() - t0).count());
  detail::set_index_figures(p.stats, shape);
  return std::move(p.stats);
}

PrepareStats prepare_file(const Volume& v, const ValueRange& range, const PrepareOptions& o, const std::string& path,
                          const Progress& progress, Volume* release) {
  check_output_path(path);  // before minutes of work, not after
  if (detail::can_sink(o)) return prepare_sunk(v, range, o, path, progress, release);
  PreparedGrid p = detail::prepare_unindexed(v, range, o, progress, release);
  detail::set_index_figures(p.stats, interval_tree_shape(p.grid, o.tree_depth));
  const auto t0 = Clock::now();
  report(progress, "save", 0);
  save_grid(p, path);
  report(progress, "save", 1);
  detail::record_stage(p.stats, "save", std::chrono::duration<double>(Clock::now() - t0).count());
  return std::move(p.stats);
}

}  // namespace

PrepareStats prepare_to_file(Volume&& v, const ValueRange& range, const PrepareOptions& o, const std::string& path,
                             const Progress& progress) {
  return prepare_file(v, range, o, path, progress, &v);
}

PrepareStats prepare_to_file(const Volume& v, const PrepareOptions& o, const std::string& path, const Progress& progress) {
  return prepare_file(v, value_range(v), o, path, progress, nullptr);
}

PrepareStats prepare_to_file(Volume&& v, const PrepareOptions& o, const std::string& path, const Progress& progress) {
  const ValueRange range = value_range(v);
  return prepare_file(v, range, o, path, progress, &v);
}

}  // namespace adaptiso
