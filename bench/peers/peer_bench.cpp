// The peers of scripts/bench.sh, on exactly the data adaptiso sees (volumes read by adaptiso's
// readers, so every method gets the same voxels). Prints one JSON object per measurement; times
// exclude I/O and are the best of --repeat runs after a warm-up. Meshes are written as PLY for the
// surface-distance comparison.
//   peer_bench vtk VOLUME ISO OUT_PREFIX       flying edges (SMP) and marching cubes
//   peer_bench fe VOLUME ISO OUT.ply           flying edges (SMP) alone
//   peer_bench vdb VOLUME ISO OUT_PREFIX       OpenVDB volumeToMesh at adaptivity 0, 0.25, 0.5, 1
//   peer_bench simplify MESH.ply TRIANGLES OUT.ply   meshoptimizer simplification to a triangle count
//   peer_bench vtkgrid GRID.vtu ISO[,ISO...]   vtkContour3DLinearGrid with a vtkSpanSpace scalar tree
//   peer_bench vtksweep VOLUME ISO[,ISO...]    flying edges per iso-value
//   peer_bench world VOLUME MESH.ply           rewrite a grid-frame mesh (scikit-image's) in world coordinates
//   peer_bench dump VOLUME OUT.raw             float32 raw copy (for scikit-image)
#include <meshoptimizer.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Dense.h>
#include <openvdb/tools/VolumeToMesh.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <cstring>

#include "adaptiso/mesh_io.hpp"
#include "adaptiso/volume_io.hpp"
#include "peer_vtk.hpp"
#include "timing.hpp"

using namespace adaptiso;
using Clock = std::chrono::steady_clock;

static int repeat = 3;

// Peers mesh in the grid frame (spacing ⊙ index); adaptiso writes world coordinates (origin and
// direction applied). Bring peer meshes into the same frame before comparing.
void to_world(const Volume& v, Mesh& m) {
  for (auto& p : m.positions) {
    Vec3 w = v.grid_to_world({p[0], p[1], p[2]});
    p = {float(w[0]), float(w[1]), float(w[2])};
  }
}

Mesh to_mesh(const PeerMesh& p) {
  Mesh m;
  m.positions.resize(p.xyz.size() / 3);
  std::memcpy(m.positions.data(), p.xyz.data(), p.xyz.size() * 4);
  m.triangles.resize(p.triangles.size() / 3);
  std::memcpy(m.triangles.data(), p.triangles.data(), p.triangles.size() * 4);
  return m;
}

void print(const std::string& method, const std::string& extra, std::size_t tris, double secs) {
  std::printf("{\"method\":\"%s\",%s\"triangles\":%zu,\"seconds\":%.6f,\"threads\":%u}\n", method.c_str(), extra.c_str(), tris, secs,
              std::thread::hardware_concurrency());
  std::fflush(stdout);
}

// The volume's values as floats, x fastest, with its dimensions: what VTK's filters take.
struct Floats {
  std::vector<float> values;
  int dims[3];
};

Floats as_floats(const Volume& v) {
  Floats f{std::vector<float>(static_cast<std::size_t>(v.voxel_count())), {int(v.dims[0]), int(v.dims[1]), int(v.dims[2])}};
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) f.values[i] = float(v.at(i));
  return f;
}

// Flying edges (SMP) at iso: timed, written to path in world coordinates, and printed.
void flying_edges_to(const Volume& v, const Floats& f, double iso, const std::string& path) {
  PeerMesh pm;
  std::string backend;
  const double t = vtk_flying_edges(f.values.data(), f.dims, v.spacing.data(), iso, repeat, pm, backend);
  Mesh m = to_mesh(pm);
  to_world(v, m);
  write_mesh(m, path);
  print("vtkFlyingEdges3D", "\"smp\":\"" + backend + "\",", m.triangle_count(), t);
}

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: see the comment at the top of peer_bench.cpp\n");
    return 2;
  }
  const std::string cmd = argv[1];
  if (const char* r = std::getenv("PEER_REPEAT")) repeat = std::max(1, std::atoi(r));
  if (cmd == "dump") {
    Volume v = read_volume(argv[2]);
    const Floats f = as_floats(v);
    std::ofstream(argv[3], std::ios::binary).write(reinterpret_cast<const char*>(f.values.data()), std::streamsize(f.values.size() * 4));
    std::printf("{\"dims\":[%lld,%lld,%lld],\"spacing\":[%g,%g,%g]}\n", (long long)v.dims[0], (long long)v.dims[1], (long long)v.dims[2],
                v.spacing[0], v.spacing[1], v.spacing[2]);
    return 0;
  }
  if (cmd == "vtk") {
    Volume v = read_volume(argv[2]);
    const double iso = std::stod(argv[3]);
    const std::string prefix = argv[4];
    const Floats f = as_floats(v);
    flying_edges_to(v, f, iso, prefix + "flying_edges.ply");
    PeerMesh pm;
    const double t = vtk_marching_cubes(f.values.data(), f.dims, v.spacing.data(), iso, repeat, pm);
    Mesh m = to_mesh(pm);
    to_world(v, m);
    write_mesh(m, prefix + "marching_cubes.ply");
    print("vtkMarchingCubes", "", m.triangle_count(), t);
    return 0;
  }
  if (cmd == "fe") {  // flying edges alone: the start of "flying edges + meshoptimizer" in bench/simplify.py
    Volume v = read_volume(argv[2]);
    flying_edges_to(v, as_floats(v), std::stod(argv[3]), argv[4]);
    return 0;
  }
  if (cmd == "world") {  // peer_bench world VOLUME MESH.ply: rewrite a grid-frame mesh in world coordinates
    Volume v = read_volume(argv[2]);
    Mesh m = read_ply(argv[3]);
    to_world(v, m);
    write_mesh(m, argv[3]);
    return 0;
  }
  if (cmd == "vtksweep") {  // flying edges per iso-value, for the sweep plot
    Volume v = read_volume(argv[2]);
    const Floats f = as_floats(v);
    std::stringstream ss(argv[3]);
    for (std::string tok; std::getline(ss, tok, ',');) {
      PeerMesh pm;
      std::string backend;
      const double iso = std::stod(tok);
      double t = vtk_flying_edges(f.values.data(), f.dims, v.spacing.data(), iso, repeat, pm, backend);
      print("vtkFlyingEdges3D", "\"iso\":" + tok + ",", pm.triangles.size() / 3, t);
    }
    return 0;
  }
  if (cmd == "vdb") {
    openvdb::initialize();
    Volume v = read_volume(argv[2]);
    const double iso = std::stod(argv[3]);
    const std::string prefix = argv[4];
    // OpenVDB meshes the zero crossing of v - iso (dense copy, background 0, no pruning).
    openvdb::tools::Dense<float, openvdb::tools::LayoutXYZ> dense(
        openvdb::CoordBBox(openvdb::Coord(0, 0, 0), openvdb::Coord(int(v.dims[0] - 1), int(v.dims[1] - 1), int(v.dims[2] - 1))));
    for (std::int64_t k = 0; k < v.dims[2]; ++k)
      for (std::int64_t j = 0; j < v.dims[1]; ++j)
        for (std::int64_t i = 0; i < v.dims[0]; ++i) dense.setValue(openvdb::Coord(int(i), int(j), int(k)), float(v.at(i, j, k) - iso));
    auto grid = openvdb::FloatGrid::create(0.0f);
    // The volume's outside counts as below the iso-value (air in a CT): OpenVDB closes surfaces that
    // touch the border there, which flying edges leaves open.
    const float below = float(value_range(v).min - iso) - 1.0f;
    grid = openvdb::FloatGrid::create(below);
    openvdb::tools::copyFromDense(dense, *grid, 0.0f);
    for (double adaptivity : {0.0, 0.25, 0.5, 1.0}) {
      std::vector<openvdb::Vec3s> pts;
      std::vector<openvdb::Vec3I> tris;
      std::vector<openvdb::Vec4I> quads;
      double t = best_of(repeat, [&] {
        pts.clear(), tris.clear(), quads.clear();
        openvdb::tools::volumeToMesh(*grid, pts, tris, quads, 0.0, adaptivity);
      });
      Mesh m;
      for (const auto& p : pts) m.positions.push_back({float(p[0] * v.spacing[0]), float(p[1] * v.spacing[1]), float(p[2] * v.spacing[2])});
      for (const auto& q : tris) m.triangles.push_back({q[0], q[1], q[2]});
      for (const auto& q : quads) {
        m.triangles.push_back({q[0], q[1], q[2]});
        m.triangles.push_back({q[0], q[2], q[3]});
      }
      to_world(v, m);
      char name[64];
      std::snprintf(name, sizeof name, "openvdb_%.2f.ply", adaptivity);
      write_mesh(m, prefix + name);
      char extra[64];
      std::snprintf(extra, sizeof extra, "\"adaptivity\":%.2f,", adaptivity);
      print("openvdb.volumeToMesh", extra, m.triangle_count(), t);
    }
    return 0;
  }
  if (cmd == "simplify") {
    Mesh m = read_ply(argv[2]);
    const std::size_t target = std::min<std::size_t>(std::stoull(argv[3]), m.triangle_count());  // cannot grow a mesh
    std::vector<unsigned int> idx(m.triangle_count() * 3), out(idx.size());
    std::memcpy(idx.data(), m.triangles.data(), idx.size() * 4);
    std::size_t n = 0;
    double t = best_of(repeat, [&] {
      n = meshopt_simplify(out.data(), idx.data(), idx.size(), &m.positions[0][0], m.vertex_count(), 12, target * 3, 1.0f);
    });
    Mesh s;
    s.positions = m.positions;
    s.triangles.resize(n / 3);
    std::memcpy(s.triangles.data(), out.data(), n * 4);
    write_mesh(s, argv[4]);
    print("meshoptimizer.simplify", "\"target\":" + std::to_string(target) + ",", s.triangle_count(), t);
    return 0;
  }
  if (cmd == "vtkgrid") {
    std::vector<double> isos;
    std::stringstream ss(argv[3]);
    for (std::string tok; std::getline(ss, tok, ',');) isos.push_back(std::stod(tok));
    vtk_grid_contours(argv[2], isos, repeat);
    return 0;
  }
  std::fprintf(stderr, "unknown command %s\n", cmd.c_str());
  return 2;
}
