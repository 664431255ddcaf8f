// Chunked parallel simplification (simplify.hpp) against one pass over the whole mesh, in one run.
// Usage: bench_simplify MESH.ply DISTANCE[,DISTANCE...] [CHUNK,... [OUT.ply]]   (distance in the
// mesh's units; chunk sizes in triangles, 0 = one pass; default 0,1000000,250000). Prints one JSON
// object per (distance, chunk size): the median of 3 runs in seconds, triangles after, chunks, the
// mean symmetric distance to the unsimplified mesh (surface_distance.hpp), and the ratio of time
// and triangles against the one-pass run of the same distance. OUT.ply receives the last
// simplified mesh: bench/simplify.py times the peer's one-pass simplification this way (unchecked:
// meshoptimizer's estimate alone, as a peer uses it).
#include <cstdio>
#include <limits>
#include <vector>

#include "adaptiso/mesh_io.hpp"
#include "adaptiso/simplify.hpp"
#include "adaptiso/surface_distance.hpp"
#include "bench_util.hpp"

using namespace adaptiso;

using bench::parse_list;

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: bench_simplify MESH.ply DISTANCE[,DISTANCE...] [CHUNK,... [OUT.ply]]\n");
    return 2;
  }
  const Mesh mesh = read_ply(argv[1]);
  const std::vector<double> chunks = argc > 3 ? parse_list(argv[3]) : std::vector<double>{0, 1000000, 250000};
  for (double d : parse_list(argv[2])) {
    double one_pass_seconds = 0, one_pass_triangles = 0;
    for (double c : chunks) {
      const std::size_t size = c > 0 ? static_cast<std::size_t>(c) : std::numeric_limits<std::size_t>::max();
      SimplifyStats st;
      Mesh simplified;
      const double seconds = bench::median_time([&] { simplified = simplify_mesh(mesh, d, &st, {size}); }, 3);
      const SurfaceDistance sd = surface_distance(simplified, mesh);
      if (c == 0) one_pass_seconds = seconds, one_pass_triangles = static_cast<double>(st.triangles_after);
      std::printf(
          "{\"distance\": %g, \"chunk_triangles\": %g, \"chunks\": %zu, \"triangles_before\": %zu, \"triangles_after\": %zu, "
          "\"mean_distance\": %.5f, \"seconds\": %.4f, \"time_vs_one_pass\": %.3f, \"triangles_vs_one_pass\": %.4f}\n",
          d, c, st.chunks, st.triangles_before, st.triangles_after, 0.5 * (sd.a_to_b.mean + sd.b_to_a.mean), seconds,
          one_pass_seconds > 0 ? seconds / one_pass_seconds : 0.0,
          one_pass_triangles > 0 ? static_cast<double>(st.triangles_after) / one_pass_triangles : 0.0);
      std::fflush(stdout);
      if (argc > 4) write_mesh(simplified, argv[4]);
    }
  }
  return 0;
}
