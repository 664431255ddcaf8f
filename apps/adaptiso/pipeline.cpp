// The preprocessing pipeline (see pipeline.hpp).
#include "pipeline.hpp"

#include <fmt/format.h>

#include <cmath>
#include <cstdlib>
#include <fstream>

#include "adaptiso/error.hpp"
#include "adaptiso/gradients.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/number.hpp"
#include "adaptiso/tetrahedralize.hpp"
#include "cli_common.hpp"

namespace adaptiso::cli {

void PipelineFlags::add(CLI::App* app) {
  app->add_option("--tree-depth", tree_depth, "Depth of the interval tree used for extraction")->capture_default_str()->check(CLI::Range(0, 24));
  app->add_flag("--sequential-delaunay", sequential_delaunay, "Use CGAL's sequential triangulation (the parallel one is the default)");
}

namespace {

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

}  // namespace

Prepared prepare_grid(const Volume& v, const std::string& source_path, const ReduceFlags& rf, const PipelineFlags& pf,
                      const Progress& cb) {
  Prepared p;
  nlohmann::json peak;
  peak["load"] = peak_rss_and_reset();
  auto t0 = Clock::now();
  ReduceResult r = reduce(v, rf.options(), cb);
  const double t_reduce = seconds_since(t0);
  peak["reduce"] = peak_rss_and_reset();
  auto range = value_range(v);
  p.grid.source = {v.dims, v.spacing, v.origin, v.direction, std::string(scalar_name(v.type)), range.min, range.max,
                   rf.method, r.max_error, r.threshold, source_path};
  t0 = Clock::now();
  TetrahedralizeOptions topt;
  topt.parallel = !pf.sequential_delaunay;
  tetrahedralize(v, r.kept, p.grid, topt, cb);
  const double t_tet = seconds_since(t0);
  peak["tetrahedralize"] = peak_rss_and_reset();
  t0 = Clock::now();
  {
    VertexRings rings = vertex_rings(p.grid);
    compute_gradients(p.grid, rings, cb);
  }
  const double t_grad = seconds_since(t0);
  peak["gradients"] = peak_rss_and_reset();
  t0 = Clock::now();
  ReconstructionError pl = piecewise_linear_error(v, p.grid, cb);
  const double t_pl = seconds_since(t0);
  peak["pl_error"] = peak_rss_and_reset();
  t0 = Clock::now();
  report(cb, "index", 0);
  p.index = build_interval_tree(p.grid, pf.tree_depth);
  const double t_index = seconds_since(t0);
  peak["index"] = peak_rss_and_reset();
  const auto& g = p.grid;
  p.stats = {{"voxels", v.voxel_count()},
             {"kept", g.vertex_count()},
             {"ratio", static_cast<double>(g.vertex_count()) / static_cast<double>(v.voxel_count())},
             {"tetrahedra", g.tet_count()},
             {"max_error", r.max_error},
             {"pl_max_error", pl.max},
             {"pl_rms_error", pl.rms},
             {"index_depth", p.index.depth},
             {"peak_bytes", peak},  // resident memory peak per stage (whole process, volume included)
             {"grid_bytes_per_vertex", grid_bytes_per_vertex(p.grid, p.index)},
             {"seconds", {{"reduce", t_reduce}, {"tetrahedralize", t_tet}, {"gradients", t_grad}, {"pl_error", t_pl}, {"index", t_index}}}};
  return p;
}

std::vector<double> parse_iso_values(const std::vector<std::string>& tokens, bool relative, double min, double max) {
  std::vector<double> out;
  for (const auto& s : tokens) {
    auto x = parse_finite(s);
    if (!x) throw InputError(fmt::format("--iso: '{}' is not a finite number", s));
    out.push_back(relative ? min + *x * (max - min) : *x);
  }
  if (out.empty()) throw InputError("--iso: give at least one iso-value");
  return out;
}

}  // namespace adaptiso::cli
