// The preprocessing pipeline (see prepare.hpp): every stage is a library call of its own; this
// file only composes them, times them and records the peak memory of each.
#include "adaptiso/prepare.hpp"

#include <fmt/format.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "adaptiso/delaunay.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/gradients.hpp"
#include "adaptiso/grid_file.hpp"

namespace adaptiso {
namespace {

using Clock = std::chrono::steady_clock;

// Peak resident memory of this process since the last reset (Linux: VmHWM; 0 elsewhere). Resetting
// (writing 5 to /proc/self/clear_refs) makes the next reading the peak of one stage.
std::uint64_t peak_rss_and_reset() {
  std::uint64_t kb = 0;
  std::ifstream status("/proc/self/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("VmHWM:", 0) == 0) kb = std::strtoull(line.c_str() + 6, nullptr, 10);
  std::ofstream("/proc/self/clear_refs") << "5";
  return kb * 1024;
}

// Times one stage and records its memory peak into stats.
class StageClock {
public:
  explicit StageClock(PrepareStats& stats) : stats_(stats) { peak_rss_and_reset(); }
  template <class F>
  decltype(auto) run(const char* name, F&& f) {
    const auto t0 = Clock::now();
    struct Record {  // also on the way out of an exception, so partial figures stay consistent
      PrepareStats& stats;
      const char* name;
      Clock::time_point t0;
      ~Record() { stats.stages.push_back({name, std::chrono::duration<double>(Clock::now() - t0).count(), peak_rss_and_reset()}); }
    } record{stats_, name, t0};
    return f();
  }

private:
  PrepareStats& stats_;
};

void check_options(const PrepareOptions& o) {
  if (!(o.max_error >= 0) || !std::isfinite(o.max_error))
    throw OptionError("max_error", fmt::format("must be a non-negative number, got {}", o.max_error));
  if (o.tree_depth > 24) throw OptionError("tree_depth", fmt::format("must be between 0 and 24, got {}", o.tree_depth));
}

}  // namespace

ReduceOptions reduce_options(const PrepareOptions& o) {
  ReduceOptions r;
  r.method = o.method;
  r.max_error = o.max_error;
  r.threshold = o.threshold;
  r.gradient = o.structural_gradient;
  r.sigma = o.sigma;
  r.kernel = o.kernel;
  r.relative = o.relative;
  return r;
}

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
  nlohmann::json j = {{"voxels", s.voxels},
                      {"kept", s.kept},
                      {"ratio", s.voxels ? static_cast<double>(s.kept) / static_cast<double>(s.voxels) : 0.0},
                      {"tetrahedra", s.tetrahedra},
                      {"max_error", s.max_error},
                      {"threshold", s.threshold},
                      {"index_depth", s.index_depth},
                      {"grid_bytes_per_vertex", s.grid_bytes_per_vertex},
                      {"seconds", seconds},
                      {"peak_bytes", peak}};
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
    if (auto it = j.find(key); it != j.end() && (it->is_number() || it->is_boolean())) out = it->get<std::decay_t<decltype(out)>>();
  };
  get("voxels", s.voxels);
  get("kept", s.kept);
  get("tetrahedra", s.tetrahedra);
  get("max_error", s.max_error);
  get("threshold", s.threshold);
  get("pl_max_error", s.pl_max_error);
  get("pl_rms_error", s.pl_rms_error);
  get("index_depth", s.index_depth);
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

PreparedGrid prepare(const Volume& v, const PrepareOptions& options, const Progress& progress) {
  return prepare(v, value_range(v), options, progress);
}

PreparedGrid prepare(const Volume& v, const ValueRange& range, const PrepareOptions& o, const Progress& progress) {
  check_options(o);
  PreparedGrid p;
  PrepareStats& stats = p.stats;
  StageClock clock(stats);
  const ReduceResult r = clock.run("reduce", [&] { return reduce(v, range, reduce_options(o), progress); });
  DelaunayOptions delaunay;
  delaunay.parallel = o.parallel_delaunay;
  p.grid = clock.run("tetrahedralize", [&] { return delaunay_grid(v, range, r.kept, delaunay, progress); });
  p.grid.source.method = o.method == ReduceMethod::structural ? "structural" : o.method == ReduceMethod::both ? "both" : "reconstruction";
  p.grid.source.max_error = r.max_error;
  p.grid.source.threshold = r.threshold;
  p.grid.source.file = std::filesystem::path(o.source_name).filename().string();
  clock.run("gradients", [&] {
    if (o.gradients == GradientMethod::central)
      central_difference_gradients(p.grid, v, progress);
    else
      least_squares_gradients(p.grid, progress);
  });
  if (o.measure_error) {
    const ReconstructionError pl = clock.run("pl_error", [&] { return piecewise_linear_error(v, p.grid, progress); });
    stats.pl_max_error = pl.max;
    stats.pl_rms_error = pl.rms;
  }
  p.index = clock.run("index", [&] {
    report(progress, "index", 0);
    return build_interval_tree(p.grid, o.tree_depth);
  });
  stats.voxels = v.voxel_count();
  stats.kept = p.grid.vertex_count();
  stats.tetrahedra = p.grid.tet_count();
  stats.max_error = r.max_error;
  stats.threshold = r.threshold;
  stats.index_depth = p.index.depth;
  stats.grid_bytes_per_vertex = grid_bytes_per_vertex(p.grid, p.index);
  return p;
}

}  // namespace adaptiso
