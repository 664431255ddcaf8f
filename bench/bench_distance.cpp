// Surface-adaptive extraction speed (hierarchy_query.hpp: extract_within) on a prepared grid: per
// iso-value and distance, the median of repeated queries in one warm process (a new iso-value each
// time: nothing is kept between queries), with its passes, counts and triangles.
// Usage: bench_distance GRID.adg ISO[,ISO...] DISTANCE[,DISTANCE...] [REPS] [OUT_PREFIX] [ROUNDS[,ROUNDS...]]
// Prints one JSON object per (iso, distance, rounds of collapses; default the library's); with
// OUT_PREFIX (not "-") also writes OUT_PREFIX-<iso>-<d>-<rounds>.ply.
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <string>

#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/mesh_io.hpp"
#include "bench_util.hpp"

using namespace adaptiso;

// The process's CPU seconds (all threads): steadier than wall time on a shared machine.
static double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: bench_distance GRID.adg ISO[,ISO...] DISTANCE[,DISTANCE...] [REPS] [OUT_PREFIX] [ROUNDS[,ROUNDS...]]\n");
    return 2;
  }
  const auto prepared = std::make_shared<const PreparedGrid>(load_grid(argv[1]));
  const double setup = bench::median_time([&] { HierarchyQuery q(prepared); }, 1);
  const HierarchyQuery query(prepared);
  const auto isos = bench::parse_list(argv[2]);
  const auto distances = bench::parse_list(argv[3]);
  const int reps = argc > 4 ? std::atoi(argv[4]) : 5;
  const bool write = argc > 5 && *argv[5] && std::string(argv[5]) != "-";  // "" or "-": no files
  const auto rounds = argc > 6 ? bench::parse_list(argv[6]) : std::vector<double>{double(kDefaultCollapseRounds)};
  for (double iso : isos)
    for (double d : distances)
      for (double r : rounds) {
        DistanceQueryStats st;
        Mesh mesh;
        double refine = 0, walk = 0, march = 0, collapse = 0;
        const double cpu0 = cpu_seconds();
        const double seconds = bench::median_time(
            [&] {
              mesh = query.extract_within(iso, d, &st, static_cast<int>(r));
              refine += st.refine_seconds, walk += st.walk_seconds, march += st.march_seconds, collapse += st.collapse_seconds;
            },
            reps);
        const double cpu = (cpu_seconds() - cpu0) / reps;
        if (write)
          write_mesh(mesh,
                     std::string(argv[5]) + "-" + std::to_string(iso) + "-" + std::to_string(d) + "-" + std::to_string(int(r)) + ".ply");
        std::printf(
            "{\"iso\": %g, \"distance\": %g, \"rounds\": %d, \"seconds\": %.5f, \"cpu_mean\": %.5f, \"refine_mean\": %.5f, "
            "\"walk_mean\": %.5f, \"march_mean\": %.5f, \"collapse_mean\": %.5f, "
            "\"triangles\": %zu, \"vertices\": %zu, \"collapsed\": %zu, \"collapse_rounds\": %zu, \"collapses_failed\": %zu, \"tested\": "
            "%zu, \"refined\": %zu, \"closure\": %zu, "
            "\"visited\": %zu, \"marched\": %zu, \"specks\": %zu, \"speck_triangles\": %zu, \"setup_seconds\": %.3f}\n",
            iso, d, int(r), seconds, cpu, refine / reps, walk / reps, march / reps, collapse / reps, st.triangles, st.vertices,
            st.collapsed, st.collapse_rounds, st.collapses_failed, st.tested, st.refined, st.closure, st.visited, st.tetrahedra, st.specks,
            st.speck_triangles, setup);
        std::fflush(stdout);
      }
}
