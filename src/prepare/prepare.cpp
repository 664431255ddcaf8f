// The preprocessing pipeline (see prepare.hpp): every stage is a library call of its own; this
// file only composes them, times them and records the peak memory of each.
#include "adaptiso/prepare.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <limits>
#include <optional>

#include "adaptiso/bisection.hpp"
#include "adaptiso/delaunay.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/gradients.hpp"
#include "util/memory.hpp"

namespace adaptiso {
namespace {

using Clock = std::chrono::steady_clock;

// Times one stage and records the process's peak at its end into stats.
class StageClock {
public:
  explicit StageClock(PrepareStats& stats) : stats_(stats) {}
  template <class F>
  decltype(auto) run(const char* name, F&& f) {
    const auto t0 = Clock::now();
    struct Record {  // also on the way out of an exception, so partial figures stay consistent
      PrepareStats& stats;
      const char* name;
      Clock::time_point t0;
      ~Record() { detail::record_stage(stats, name, std::chrono::duration<double>(Clock::now() - t0).count()); }
    } record{stats_, name, t0};
    return f();
  }

private:
  PrepareStats& stats_;
};

// Bytes of the grid's arrays (grid_bytes_per_vertex, without an index) and its hierarchy in memory.
std::uint64_t resident_grid_bytes(const PreparedGrid& p) {
  auto bytes = static_cast<std::uint64_t>(grid_bytes_per_vertex(p.grid, IntervalTree{}) * static_cast<double>(p.grid.vertex_count()));
  if (p.hierarchy)
    bytes += p.hierarchy->error_code.size() + p.hierarchy->displacement_code.size() +
             p.hierarchy->value_span.size() * sizeof(p.hierarchy->value_span[0]);
  return bytes;
}

void check_options(const PrepareOptions& o) {
  if (o.max_error && (!(*o.max_error >= 0) || (!std::isfinite(*o.max_error) && o.grid == GridKind::delaunay)))
    throw OptionError("max_error", fmt::format("must be a non-negative number, got {}", *o.max_error));
  if (o.tree_depth > kMaxTreeDepth)
    throw OptionError("tree_depth", fmt::format("must be between 0 and {}, got {}", kMaxTreeDepth, o.tree_depth));
  if (!(o.max_displacement >= 0) || !std::isfinite(o.max_displacement))
    throw OptionError("max_displacement", fmt::format("must be a non-negative number, got {}", o.max_displacement));
  if (o.max_displacement > 0 && o.grid != GridKind::bisection)
    throw OptionError("max_displacement", "is a criterion of the bisection grid (use the bisection grid or leave it out)");
}

}  // namespace

double default_max_error(const ValueRange& range, bool relative) {
  return relative ? kDefaultRelativeError : kDefaultRelativeError * (range.max - range.min);
}

double absolute_max_error(const PrepareOptions& o, const ValueRange& range) {
  if (!o.max_error) return o.max_displacement > 0 ? std::numeric_limits<double>::infinity() : default_max_error(range, false);
  return o.relative ? from_fraction(range, *o.max_error, FractionOf::width, "max_error") : *o.max_error;
}

PreparedGrid prepare(const Volume& v, const PrepareOptions& options, const Progress& progress) {
  return prepare(v, value_range(v), options, progress);
}

namespace {

// The paper's grid: reduction (§2.1), then Delaunay (§2.2).
TetGrid delaunay_pipeline(const Volume& v, const ValueRange& range, const PrepareOptions& o, StageClock& clock, PrepareStats& stats,
                          const Progress& progress) {
  // The bound in the unit the threshold is given in (ReduceOptions::relative covers both): reduce()
  // converts it to data units, once.
  ReduceOptions reduction = o.reduce;
  reduction.relative = o.relative;
  reduction.max_error = o.max_error ? *o.max_error : default_max_error(range, o.relative);
  const ReduceResult r = clock.run("reduce", [&] { return reduce(v, range, reduction, progress); });
  stats.max_error = r.max_error;
  stats.threshold = r.threshold;
  DelaunayOptions delaunay;
  delaunay.parallel = o.parallel_delaunay;
  TetGrid grid = clock.run("tetrahedralize", [&] { return delaunay_grid(v, range, r.kept, delaunay, progress); });
  const ReduceMethod method = o.reduce.method;
  grid.source.method = method == ReduceMethod::structural ? "structural" : method == ReduceMethod::both ? "both" : "reconstruction";
  grid.source.max_error = r.max_error;
  grid.source.threshold = r.threshold;
  return grid;
}

// What the grid's source says of the volume it came from: its own box (before padding) and file.
void describe_source(GridSource& source, const Dims& volume_dims, const PrepareOptions& o) {
  source.volume_dims = volume_dims;
  source.file = std::filesystem::path(o.source_name).filename().string();
}

// Hands the selection's grid to a PreparedGridSink: first what the file's head needs (the
// gradients, the statistics), then the tetrahedra. The sink's time is kept apart: the stage "save".
class SinkFeed final : public TetrahedraSink {
public:
  SinkFeed(detail::PreparedGridSink& sink, const Volume& lattice_volume, const Dims& volume_dims, const PrepareOptions& o,
           PrepareStats& stats, const Progress& progress)
      : sink_(sink), volume_(lattice_volume), volume_dims_(volume_dims), o_(o), stats_(stats), progress_(progress) {}
  void begin(BisectionGrid& g, std::uint64_t tets) override {
    describe_source(g.grid.source, volume_dims_, o_);
    stats_.error_bound = g.error_bound;
    stats_.kept = g.grid.volume_vertex_count();
    stats_.vertices = g.grid.vertex_count();
    stats_.tetrahedra = tets;
    const auto t0 = Clock::now();
    central_difference_gradients(g.grid, volume_, progress_);
    const auto t1 = Clock::now();
    gradient_seconds = std::chrono::duration<double>(t1 - t0).count();
    sink_.begin(stats_, g.grid, g.hierarchy);
    sink_seconds += std::chrono::duration<double>(Clock::now() - t1).count();
  }
  void write(std::span<const std::array<std::uint32_t, 4>> tets) override {
    const auto t0 = Clock::now();
    sink_.write(tets);
    sink_seconds += std::chrono::duration<double>(Clock::now() - t0).count();
  }
  double gradient_seconds = 0, sink_seconds = 0;

private:
  detail::PreparedGridSink& sink_;
  const Volume& volume_;
  Dims volume_dims_;
  const PrepareOptions& o_;
  PrepareStats& stats_;
  const Progress& progress_;
};

// The bisection grid, with its hierarchy for coarser queries; its tetrahedra to `feed`, if given.
TetGrid bisection_pipeline(const Volume& v, const ValueRange& range, const PrepareOptions& o, StageClock& clock, PreparedGrid& p,
                           const Progress& progress, SinkFeed* feed) {
  BisectionOptions b;
  b.max_error = absolute_max_error(o, range);
  b.max_displacement = o.max_displacement;
  b.share = o.select_share;
  b.sink = feed;
  const bool displacement = b.max_displacement > 0;
  const BisectionErrors errors = clock.run("error_hierarchy", [&] {
    return o.error_hierarchy ? o.error_hierarchy(v, range, displacement, progress) : bisection_errors(v, range, displacement, progress);
  });
  p.stats.max_error = b.max_error;  // before the selection: a sink's head holds them
  p.stats.max_displacement = b.max_displacement;
  BisectionGrid grid = clock.run("select", [&] { return bisection_select(v, range, errors, b, progress); });
  p.stats.error_bound = grid.error_bound;
  p.hierarchy = std::move(grid.hierarchy);
  return std::move(grid.grid);
}

// The select stage without what ran inside it for the feed: its gradients, and its sink ("save").
void split_sunk_stages(PrepareStats& stats, const SinkFeed& feed) {
  auto& select = stats.stages.back();  // the stage just recorded
  select.seconds = std::max(0.0, select.seconds - feed.gradient_seconds - feed.sink_seconds);
  const std::uint64_t peak = select.peak_bytes;
  stats.stages.push_back({"gradients", feed.gradient_seconds, peak});
  stats.stages.push_back({"save", feed.sink_seconds, peak});
}

bool central_gradients(const PrepareOptions& o) {
  return o.gradients == GradientMethod::central || (o.gradients == GradientMethod::automatic && o.grid == GridKind::bisection);
}

}  // namespace

namespace detail {

bool can_sink(const PrepareOptions& o) { return o.grid == GridKind::bisection && !o.verify && central_gradients(o); }

PreparedGrid prepare_unindexed(const Volume& v, const ValueRange& range, const PrepareOptions& o, const Progress& progress, Volume* release,
                               PreparedGridSink* sink) {
  check_options(o);
  if (sink && !can_sink(o)) throw std::logic_error("prepare_unindexed: these options' grid cannot go to a sink");
  // The grid file's loader refuses such geometry: refused here, no file is written that cannot be read.
  check_geometry(v, o.source_name.empty() ? std::string("the volume") : o.source_name);
  PreparedGrid p;
  PrepareStats& stats = p.stats;
  StageClock clock(stats);
  const bool bisection = o.grid == GridKind::bisection;
  stats.grid = bisection ? "bisection" : "delaunay";
  stats.voxels = v.voxel_count();
  stats.tree_depth = o.tree_depth;
  const Dims volume_dims = v.dims;
  // The padded lattice's volume; the volume itself goes at once when the caller gave it up.
  std::optional<Volume> padded;
  if (const Dims lattice = bisection_lattice_dims(v.dims); bisection && o.pad_lattice && lattice != v.dims) {
    check_memory(static_cast<std::uint64_t>(lattice[0] * lattice[1] * lattice[2]) * scalar_size(v.type),
                 fmt::format("the volume padded to {} x {} x {} voxels", lattice[0], lattice[1], lattice[2]), "",
                 "crop or subsample the volume");
    padded = clock.run("pad", [&] { return pad_volume(v, lattice, range); });
    if (release) release->bytes = VoxelBuffer();
  }
  const Volume& lv = padded ? *padded : v;
  std::optional<SinkFeed> feed;
  if (sink) feed.emplace(*sink, lv, volume_dims, o, stats, progress);
  p.grid = bisection ? bisection_pipeline(lv, range, o, clock, p, progress, feed ? &*feed : nullptr)
                     : delaunay_pipeline(v, range, o, clock, stats, progress);
  describe_source(p.grid.source, volume_dims, o);
  if (feed) {
    split_sunk_stages(stats, *feed);
  } else {
    clock.run("gradients", [&] {
      if (central_gradients(o))
        central_difference_gradients(p.grid, lv, progress);
      else
        least_squares_gradients(p.grid, progress);
    });
    stats.tetrahedra = p.grid.tet_count();
  }
  if (!bisection || o.verify) {
    const ReconstructionError pl = clock.run("pl_error", [&] { return piecewise_linear_error(lv, p.grid, progress); });
    stats.pl_max_error = pl.max;
    stats.pl_rms_error = pl.rms;
    if (bisection && pl.max > stats.error_bound + error_tolerance(range, stats.error_bound))
      throw std::logic_error(fmt::format("bisection grid: error {} exceeds its guaranteed bound {}", pl.max, stats.error_bound));
  }
  stats.kept = p.grid.volume_vertex_count();
  stats.vertices = p.grid.vertex_count();
  if (release) release->bytes = VoxelBuffer();
  release_free_heap();  // what the selection freed in the heap's arenas (the MR head: 9 MiB)
  return p;
}

// Peak resident memory of this process so far (Linux: VmHWM; 0 elsewhere). Never reset (writing
// to /proc/self/clear_refs would give per-stage peaks, but it also resets what getrusage, time(1)
// and wait4 report for the whole process: the bunny's 2.8 GB index peak read as 2.0 GB).
void record_stage(PrepareStats& stats, const std::string& name, double seconds) {
  stats.stages.push_back({name, seconds, process_status_bytes("VmHWM")});
}

}  // namespace detail

namespace {

// The extraction index over the grid (options.tree_depth), within `scratch` bytes beyond its
// lists, timed into stats as the stage "index".
IntervalTree build_index(const TetGrid& grid, const PrepareOptions& o, std::size_t scratch, PrepareStats& stats, const Progress& progress) {
  return StageClock(stats).run("index", [&] {
    report(progress, "index", 0);
    return build_interval_tree(grid, o.tree_depth, scratch);
  });
}

// What the index's build may hold beyond its lists (bytes) for the process's peak to stay within
// grid_bytes (the grid's bytes in memory besides the lists) plus 2.5 times volume_bytes (README
// "Memory"); what else the process holds now (VmRSS: its code and libraries, the heap's remains)
// comes out of the 2.5 volumes, 0 when nothing is left. The bunny's nodes all sort the fast way
// within it; the MR head's noisy scan, whose largest node alone would take 426 MiB that way, sorts
// its largest nodes with 2 bytes an entry.
std::size_t index_scratch(std::uint64_t volume_bytes, std::uint64_t grid_bytes) {
  const std::uint64_t resident = detail::process_status_bytes("VmRSS");
  const std::uint64_t other = resident > grid_bytes ? resident - grid_bytes : 0;
  const std::uint64_t allowance = volume_bytes / 2 * 5;
  return allowance > other ? allowance - other : 0;
}

PreparedGrid prepare_grid(const Volume& v, const ValueRange& range, const PrepareOptions& o, const Progress& progress, Volume* release) {
  const std::uint64_t volume_bytes = v.bytes.size();
  PreparedGrid p = detail::prepare_unindexed(v, range, o, progress, release);
  // At least 64 MiB: prepare's grid in memory may not fit its allowance at all (the chest CT).
  const std::size_t scratch = std::max(index_scratch(volume_bytes, resident_grid_bytes(p)), std::size_t{64} << 20);
  p.index = build_index(p.grid, o, scratch, p.stats, progress);
  p.stats.index_depth = p.index.depth;
  p.stats.grid_bytes_per_vertex = grid_bytes_per_vertex(p.grid, p.index);
  return p;
}

}  // namespace

PreparedGrid prepare(const Volume& v, const ValueRange& range, const PrepareOptions& o, const Progress& progress) {
  return prepare_grid(v, range, o, progress, nullptr);
}

PreparedGrid prepare(Volume&& v, const ValueRange& range, const PrepareOptions& o, const Progress& progress) {
  return prepare_grid(v, range, o, progress, &v);
}

PreparedGrid prepare(Volume&& v, const PrepareOptions& o, const Progress& progress) {
  const ValueRange range = value_range(v);
  return prepare_grid(v, range, o, progress, &v);
}

PreparedGrid prepare_without_index(const Volume& v, const PrepareOptions& o, const Progress& progress) {
  PreparedGrid p = detail::prepare_unindexed(v, value_range(v), o, progress, nullptr);
  detail::set_index_figures(p.stats, interval_tree_shape(p.grid, o.tree_depth));
  return p;
}

void add_index(PreparedGrid& p, const Progress& progress) {
  if (!p.index.nodes.empty() || p.grid.tet_count() == 0) return;
  report(progress, "build index", 0);
  p.index = build_interval_tree(p.grid, p.stats.tree_depth);
  report(progress, "build index", 1);
  p.stats.index_depth = p.index.depth;
  p.stats.grid_bytes_per_vertex = grid_bytes_per_vertex(p.grid, p.index);
}

namespace {

PreparedGrid coarsen_with(const PreparedGrid& fine, const BisectionOptions& b, const Progress& progress) {
  if (!fine.hierarchy) throw InputError("this grid has no bisection hierarchy: only a bisection grid can be coarsened");
  PreparedGrid p;
  StageClock clock(p.stats);
  BisectionGrid grid = clock.run("select", [&] { return bisection_coarsen(fine.grid, *fine.hierarchy, b, progress); });
  p.grid = std::move(grid.grid);
  if (b.cell_floor == 0) {
    p.hierarchy = std::move(grid.hierarchy);
  } else {
    p.tet_error_code = std::move(grid.tet_code);
    p.tet_codes = fine.hierarchy->codes;
  }
  // A fine grid without its index (prepare_without_index, a file loaded without it) gives the depth it was prepared for.
  p.stats.tree_depth = fine.index.depth ? fine.index.depth : fine.stats.tree_depth ? fine.stats.tree_depth : kDefaultTreeDepth;
  p.index = clock.run("index", [&] { return build_interval_tree(p.grid, p.stats.tree_depth); });
  p.stats.grid = "bisection";
  p.stats.voxels = fine.stats.voxels;
  p.stats.kept = p.grid.volume_vertex_count();
  p.stats.vertices = p.grid.vertex_count();
  p.stats.tetrahedra = p.grid.tet_count();
  p.stats.max_error = p.grid.source.max_error;
  p.stats.error_bound = grid.error_bound;
  p.stats.max_displacement = fine.stats.max_displacement > 0 ? std::max(b.max_displacement, fine.stats.max_displacement) : 0;
  if (b.cell_floor && p.stats.max_displacement > 0) p.stats.max_displacement = std::max(p.stats.max_displacement, grid.displacement_bound);
  p.stats.index_depth = p.index.depth;
  p.stats.grid_bytes_per_vertex = grid_bytes_per_vertex(p.grid, p.index);
  return p;
}

}  // namespace

PreparedGrid coarsen(const PreparedGrid& fine, double max_error, double max_displacement, const Progress& progress) {
  BisectionOptions b;
  b.max_error = max_error;
  b.max_displacement = max_displacement;
  return coarsen_with(fine, b, progress);
}

PreparedGrid coarsen_floored(const PreparedGrid& fine, double max_error, int cell_floor, const Progress& progress) {
  BisectionOptions b;
  b.max_error = max_error;
  b.cell_floor = cell_floor;
  return coarsen_with(fine, b, progress);
}

}  // namespace adaptiso
