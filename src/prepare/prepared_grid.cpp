// The prepared grid's statistics as JSON and the error of its surfaces (see prepared_grid.hpp):
// what prepare measured, stored in grid files and printed by --json. Apart from prepare.cpp so the
// grid file loader (and its fuzz target) needs no grid builder.
#include "adaptiso/prepared_grid.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <limits>
#include <nlohmann/json.hpp>
#include <type_traits>

namespace adaptiso {

double PrepareStats::seconds(const std::string& stage) const {
  for (const auto& s : stages)
    if (s.name == stage) return s.seconds;
  return 0;
}

std::string to_json(const PrepareStats& s) {
  nlohmann::json seconds = nlohmann::json::object(), peak = nlohmann::json::object();
  for (const auto& st : s.stages) {
    seconds[st.name] = st.seconds;
    peak[st.name] = st.peak_bytes;
  }
  nlohmann::json j = {{"grid", s.grid},
                      {"voxels", s.voxels},
                      {"kept", s.kept},
                      {"ratio", s.voxels ? static_cast<double>(s.kept) / static_cast<double>(s.voxels) : 0.0},
                      {"tetrahedra", s.tetrahedra},
                      {"max_error", s.max_error},
                      {"threshold", s.threshold},
                      {"index_depth", s.index_depth},
                      {"tree_depth", s.tree_depth},
                      {"grid_bytes_per_vertex", s.grid_bytes_per_vertex},
                      {"seconds", seconds},
                      {"peak_bytes", peak}};
  if (s.vertices) j["vertices"] = s.vertices;  // files before 2026-11-29 did not count them
  if (s.error_bound >= 0) j["error_bound"] = s.error_bound;
  if (s.max_displacement > 0) j["max_displacement"] = s.max_displacement;
  if (s.pl_max_error >= 0) {
    j["pl_max_error"] = s.pl_max_error;
    j["pl_rms_error"] = s.pl_rms_error;
  }
  return j.dump();
}

PrepareStats prepare_stats_from_json(const std::string& text) {
  PrepareStats s;
  const auto j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.is_object()) return s;
  auto get = [&](const char* key, auto& out) {
    using T = std::decay_t<decltype(out)>;
    const auto it = j.find(key);
    if (it == j.end()) return;
    if constexpr (std::is_integral_v<T>) {
      // Counts only as whole numbers in range: a float or a negative number converted to an
      // unsigned type is undefined behaviour (a grid file's metadata held 2.13e64 there).
      if (it->is_number_unsigned() && it->template get<std::uint64_t>() <= std::numeric_limits<T>::max())
        out = static_cast<T>(it->template get<std::uint64_t>());
    } else if (it->is_number()) {
      out = it->template get<T>();
    }
  };
  if (auto it = j.find("grid"); it != j.end() && it->is_string()) s.grid = it->get<std::string>();
  get("voxels", s.voxels);
  get("kept", s.kept);
  get("vertices", s.vertices);
  get("tetrahedra", s.tetrahedra);
  get("max_error", s.max_error);
  if (auto it = j.find("max_error"); it != j.end() && it->is_null())
    s.max_error = std::numeric_limits<double>::infinity();  // no error criterion
  get("threshold", s.threshold);
  get("error_bound", s.error_bound);
  get("max_displacement", s.max_displacement);
  get("pl_max_error", s.pl_max_error);
  get("pl_rms_error", s.pl_rms_error);
  get("index_depth", s.index_depth);
  get("tree_depth", s.tree_depth);
  get("grid_bytes_per_vertex", s.grid_bytes_per_vertex);
  if (auto it = j.find("seconds"); it != j.end() && it->is_object())
    for (auto st = it->begin(); st != it->end(); ++st) {
      if (!st->is_number()) continue;
      StageStats stage{st.key(), st->get<double>(), 0};
      if (auto p = j.find("peak_bytes"); p != j.end() && p->is_object() && p->contains(st.key()) && (*p)[st.key()].is_number_unsigned())
        stage.peak_bytes = (*p)[st.key()].get<std::uint64_t>();
      s.stages.push_back(stage);
    }
  return s;
}

namespace {
double bytes_per_vertex(std::uint64_t vertices, std::uint64_t tets, std::uint64_t entries, std::uint64_t nodes) {
  const double bytes = static_cast<double>(vertices) * (12.0 + 8 + 12) + static_cast<double>(tets) * 16.0 +
                       static_cast<double>(entries) * 8.0 + static_cast<double>(nodes) * 24.0;
  return vertices ? bytes / static_cast<double>(vertices) : 0;
}
}  // namespace

double grid_bytes_per_vertex(const TetGrid& grid, const IntervalTree& index) {
  return bytes_per_vertex(grid.vertex_count(), grid.tet_count(), index.entries(), index.nodes.size());
}

namespace detail {
void set_index_figures(PrepareStats& stats, const IntervalTreeShape& shape) {
  stats.index_depth = shape.depth;  // reduced where there are fewer tetrahedra than leaves
  stats.grid_bytes_per_vertex = bytes_per_vertex(stats.vertices, stats.tetrahedra, shape.entries, shape.nodes());
}
}  // namespace detail

double surface_error(const PrepareStats& s) { return s.error_bound >= 0 ? s.error_bound : s.pl_max_error; }

double surface_error_bound(const PreparedGrid& g, const std::vector<std::uint32_t>& tetrahedra) {
  if (g.tet_error_code.empty()) return surface_error(g.stats);
  const std::uint8_t worst = tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, tetrahedra.size(), 1 << 14), std::uint8_t{0},
      [&](const auto& r, std::uint8_t m) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) m = std::max(m, g.tet_error_code[tetrahedra[i]]);
        return m;
      },
      [](std::uint8_t a, std::uint8_t b) { return std::max(a, b); });
  return tetrahedra.empty() ? 0.0 : g.tet_codes.error(worst);
}

}  // namespace adaptiso
