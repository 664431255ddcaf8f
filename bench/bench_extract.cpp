// Extraction speed (§2.4): per iso-value, the stateless tree query vs the brute-force scan, a fresh
// extraction (query + marching) vs scan + marching, and small iso-value steps (0.1 % and 1 % of the
// range) through one Extractor, whose sweep walks only the entries between the old and new value.
// Usage: bench_extract GRID.adg ISO[,ISO...] [DEPTH,...]   (iso in data units; depths rebuild the tree)
// Prints one JSON object per (depth, iso); times are medians of 5 runs, in seconds. extract_fresh is
// query + sort + march without a sweep state; extract_scan replaces the query by the scan.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "bench_util.hpp"
#include "extract/march_detail.hpp"  // the fresh march with reused buffers, as the Extractor runs it

using namespace adaptiso;
using Clock = std::chrono::steady_clock;

using bench::median_time;
using bench::parse_list;

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: bench_extract GRID.adg ISO[,ISO...] [DEPTH,...]\n");
    return 2;
  }
  auto t0 = Clock::now();
  const auto prepared = std::make_shared<const PreparedGrid>(load_grid(argv[1]));
  const TetGrid& grid = prepared->grid;
  const IntervalTree& stored = prepared->index;
  const double load = std::chrono::duration<double>(Clock::now() - t0).count();
  const auto isos = parse_list(argv[2]);
  std::vector<double> depths = argc > 3 ? parse_list(argv[3]) : std::vector<double>{double(stored.depth)};
  const double range = grid.source.max - grid.source.min;
  std::fprintf(stderr, "loaded %s: %zu vertices, %zu tetrahedra in %.2f s\n", argv[1], grid.vertex_count(), grid.tet_count(), load);
  for (double d : depths) {
    auto p = std::make_shared<PreparedGrid>();
    p->grid = grid;
    double build = 0;
    if (static_cast<std::uint32_t>(d) == stored.depth)
      p->index = stored;
    else
      build = median_time([&] { p->index = build_interval_tree(grid, static_cast<std::uint32_t>(d)); }, 1);
    const IntervalTree& tree = p->index;
    for (double iso : isos) {
      std::vector<std::uint32_t> act;
      Mesh mesh;
      const double q_tree = median_time([&] {
        act.clear();
        query_active(tree, grid, iso, act);
      });
      const double q_scan = median_time([&] {
        act.clear();
        scan_active(grid, iso, act);
      });
      const std::size_t active = act.size();
      // A fresh extraction without a sweep state: query, sort by id (as the Extractor does), march.
      detail::MarchScratch scratch;
      std::vector<std::uint64_t> bitmap;
      const double march = median_time([&] {
        act.clear();
        query_active(tree, grid, iso, act);
        detail::sort_ids(act, grid.tet_count(), bitmap);
        detail::march_tetrahedra_into(grid, act, iso, mesh, scratch, nullptr, nullptr);
      });
      const std::size_t tris = mesh.triangle_count();
      double init = 0, step_small = 0, step_large = 0, sweep_small = 0, sweep_large = 0;
      std::uint64_t walked_small = 0, walked_large = 0;
      std::size_t marched_small = 0, marched_large = 0;
      int incremental = 0;
      {
        Extractor ex(p);
        init = median_time(
            [&] {
              Extractor fresh(p);
              fresh.extract(iso);
            },
            1);
        ex.extract(iso);
        // Alternate up and down so every run is the same step.
        double sign = 1;
        auto step = [&](double frac, double& total, double& sweep, std::uint64_t& walked, std::size_t& marched) {
          std::vector<double> tt, ts;
          for (int r = 0; r < 6; ++r) {
            auto a = Clock::now();
            ExtractStats st = ex.extract(iso + sign * frac * range);
            incremental += st.incremental;
            tt.push_back(std::chrono::duration<double>(Clock::now() - a).count());
            ts.push_back(st.sweep_seconds);
            walked = st.walked;
            marched = st.marched;
            ex.extract(iso);
            sign = -sign;
          }
          std::sort(tt.begin(), tt.end());
          std::sort(ts.begin(), ts.end());
          total = tt[tt.size() / 2];
          sweep = ts[ts.size() / 2];
        };
        step(0.001, step_small, sweep_small, walked_small, marched_small);
        step(0.01, step_large, sweep_large, walked_large, marched_large);
      }
      std::printf(
          "{\"grid\":\"%s\",\"tetrahedra\":%zu,\"depth\":%u,\"build_seconds\":%.3f,\"iso\":%g,\"active\":%zu,\"active_fraction\":%.5f,"
          "\"triangles\":%zu,\"query_tree\":%.6f,\"query_scan\":%.6f,\"extract_fresh\":%.6f,\"extract_scan\":%.6f,"
          "\"tree_vs_scan\":%.2f,\"first_extract_with_state\":%.6f,\"step_0.1%%\":%.6f,\"sweep_0.1%%\":%.6f,\"walked_0.1%%\":%llu,"
          "\"marched_0.1%%\":%zu,"
          "\"step_1%%\":%.6f,\"sweep_1%%\":%.6f,\"walked_1%%\":%llu,\"marched_1%%\":%zu,\"sweep_step_vs_fresh_query_0.1%%\":%.3f,\"step_vs_"
          "fresh_extract_0.1%%\":%.3f,\"step_vs_fresh_extract_1%%\":%.3f,\"incremental_steps\":%d}\n",
          argv[1], grid.tet_count(), tree.depth, build, iso, active, double(active) / double(grid.tet_count()), tris, q_tree, q_scan, march,
          q_scan - q_tree + march, q_scan / q_tree, init, step_small, sweep_small, (unsigned long long)walked_small, marched_small,
          step_large, sweep_large, (unsigned long long)walked_large, marched_large, sweep_small / q_tree, step_small / march,
          step_large / march, incremental);
      std::fflush(stdout);
    }
  }
}
