// Preparation straight into a grid file (see prepare_to_file.hpp): prepare()'s steps before the
// index (prepare.hpp), then the grid file's streaming writer (grid_file_stream.hpp), which builds
// the index once the grid's positions and gradients are on disk and freed.
#include "adaptiso/prepare_to_file.hpp"

#include <algorithm>
#include <chrono>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/grid_file.hpp"
#include "io/grid_file_stream.hpp"

namespace adaptiso {
namespace {

using Clock = std::chrono::steady_clock;

PrepareStats prepare_file(const Volume& v, const ValueRange& range, const PrepareOptions& o, const std::string& path,
                          const Progress& progress, Volume* release) {
  check_output_path(path);  // before minutes of work, not after
  const std::uint64_t volume_bytes = v.bytes.size();
  PreparedGrid p = detail::prepare_unindexed(v, range, o, progress, release);
  const IntervalTreeShape shape = interval_tree_shape(p.grid, o.tree_depth);
  p.stats.index_depth = shape.depth;
  p.stats.grid_bytes_per_vertex = detail::grid_bytes_per_vertex(p.grid, shape);
  const auto t0 = Clock::now();
  detail::save_grid_building_index(
      p, path, shape,
      [&](std::uint64_t file_bytes) {
        // The grid's part of the file: what the lists and the nodes (as held in memory) leave.
        const std::uint64_t index_bytes = shape.entries * 8 + shape.nodes() * sizeof(IntervalTree::Node);
        return detail::index_scratch(volume_bytes, file_bytes > index_bytes ? file_bytes - index_bytes : 0);
      },
      [&](const TetGrid& grid, std::size_t scratch) {
        // At least 16 MiB: the nodes that do not fit sort with 2 bytes an entry.
        return detail::build_index(grid, o, std::max(scratch, std::size_t{16} << 20), p.stats, progress);
      });
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count() - p.stats.seconds("index");
  detail::record_stage(p.stats, "save", seconds);
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
