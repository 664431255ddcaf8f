// Preparation straight into a grid file (see prepare_to_file.hpp): prepare()'s steps before the
// index (prepare.hpp), then the grid file without its index, which loading builds (grid_file.hpp:
// faster than checking a stored one).
#include "adaptiso/prepare_to_file.hpp"

#include <chrono>

#include "adaptiso/atomic_file.hpp"
#include "adaptiso/grid_file.hpp"

namespace adaptiso {
namespace {

using Clock = std::chrono::steady_clock;

PrepareStats prepare_file(const Volume& v, const ValueRange& range, const PrepareOptions& o, const std::string& path,
                          const Progress& progress, Volume* release) {
  check_output_path(path);  // before minutes of work, not after
  PreparedGrid p = detail::prepare_unindexed(v, range, o, progress, release);
  const IntervalTreeShape shape = interval_tree_shape(p.grid, o.tree_depth);
  p.stats.index_depth = shape.depth;  // the depth it will have (fewer tetrahedra than leaves: reduced), loading builds it at
  p.stats.grid_bytes_per_vertex = detail::grid_bytes_per_vertex(p.grid, shape);  // as loaded, with the index
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
