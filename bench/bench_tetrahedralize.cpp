// Delaunay tetrahedrization throughput on lattice input (points/s), sequential vs CGAL's
// Parallel_tag, on a full 100³ lattice (1 M maximally cospherical points) and on the kept set of a
// real volume when ../shared/data is present. Prints one JSON object per case.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <numeric>

#include "adaptiso/delaunay.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/volume_io.hpp"

using namespace adaptiso;

static void run(const char* name, const Volume& v, const std::vector<std::int64_t>& kept) {
  for (bool par : {false, true}) {
    auto t0 = std::chrono::steady_clock::now();
    DelaunayOptions o;
    o.parallel = par;
    const TetGrid g = delaunay_grid(v, value_range(v), kept, o);
    double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("{\"case\":\"%s\",\"parallel\":%s,\"points\":%zu,\"tetrahedra\":%zu,\"seconds\":%.3f,\"points_per_second\":%.0f}\n", name,
                par ? "true" : "false", kept.size(), g.tet_count(), s, static_cast<double>(kept.size()) / s);
    std::fflush(stdout);
  }
}

int main(int argc, char** argv) {
  std::int64_t n = argc > 1 ? std::atoll(argv[1]) : 100;
  Volume lattice = make_volume({n, n, n}, ScalarType::u8);
  std::vector<std::int64_t> all(static_cast<std::size_t>(lattice.voxel_count()));
  std::iota(all.begin(), all.end(), 0);
  run("full_lattice", lattice, all);
  std::string data = std::getenv("ADAPTISO_DATA") ? std::getenv("ADAPTISO_DATA") : ADAPTISO_SOURCE_DIR "/../shared/data";
  if (std::filesystem::exists(data + "/ct_chest_lidc2.nhdr")) {
    Volume v = read_volume(data + "/ct_chest_lidc2.nhdr");
    ReduceOptions o;
    o.max_error = 0.05;
    o.relative = true;
    run("ct_chest_lidc2_kept_e0.05", v, reduce(v, o).kept);
  }
}
