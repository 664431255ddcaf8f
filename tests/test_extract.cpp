// Extraction (§2.4): the interval tree against the brute-force scan, marching tetrahedra against
// analytic fields (plane, sphere), mesh topology (watertight, manifold, oriented), the mesh files,
// and the extract / run commands.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <map>
#include <numeric>
#include <random>
#include <set>

#include "adaptiso/extract.hpp"
#include "adaptiso/gradients.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/interval_tree.hpp"
#include "adaptiso/mesh.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/tetrahedralize.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

TetGrid build(const Volume& v, const std::vector<std::int64_t>& kept) { return testutil::build_grid(v, kept); }

std::vector<std::int64_t> all_voxels(const Volume& v) {
  std::vector<std::int64_t> k(static_cast<std::size_t>(v.voxel_count()));
  std::iota(k.begin(), k.end(), 0);
  return k;
}

// A random kept set (corners always) of a volume with small integer values: many ties, many
// constant tetrahedra, many vertices exactly at the iso-values tried.
TetGrid random_grid(std::mt19937& rng, int levels) {
  Dims d{2 + std::int64_t(rng() % 7), 2 + std::int64_t(rng() % 7), 2 + std::int64_t(rng() % 7)};
  Volume v = make_volume(d, ScalarType::f32);
  v.spacing = {1.0 + (rng() % 3) * 0.5, 1.0, 0.5 + (rng() % 2)};
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, double(rng() % levels));
  std::vector<std::int64_t> kept;
  auto corners = volume_corners(v);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i)
    if (rng() % 3 != 0 || std::find(corners.begin(), corners.end(), i) != corners.end()) kept.push_back(i);
  return build(v, kept);
}

std::vector<std::uint32_t> sorted(std::vector<std::uint32_t> a) {
  std::sort(a.begin(), a.end());
  return a;
}

testutil::EdgeCensus topology(const Mesh& m, const GridSource& s) { return testutil::edge_census(m, s.dims, s.spacing); }

double triangle_area(const Mesh& m, const std::array<std::uint32_t, 3>& t) {
  Mesh one;
  one.positions = {m.positions[t[0]], m.positions[t[1]], m.positions[t[2]]};
  one.triangles = {{0, 1, 2}};
  return mesh_area(one);
}

// The Extractor's mesh equals a fresh march up to vertex numbering and triangle order: the same
// triangles (each as its three cut edges, in the same corner order) the same number of times, bit-identical
// positions and normals per edge, one vertex per edge and no unused vertex.
testing::AssertionResult same_surface(const Extractor& ex, const Mesh& ref, const std::vector<std::uint64_t>& ref_edges) {
  const Mesh& m = ex.mesh();
  const auto& edges = ex.vertex_edges();
  if (m.vertex_count() != ref.vertex_count() || edges.size() != m.vertex_count())
    return testing::AssertionFailure() << "vertices " << m.vertex_count() << " vs " << ref.vertex_count();
  if (m.triangle_count() != ref.triangle_count())
    return testing::AssertionFailure() << "triangles " << m.triangle_count() << " vs " << ref.triangle_count();
  std::map<std::uint64_t, std::uint32_t> ref_vertex;  // edge -> reference vertex
  for (std::uint32_t r = 0; r < ref_edges.size(); ++r) ref_vertex[ref_edges[r]] = r;
  if (ref_vertex.size() != ref_edges.size()) return testing::AssertionFailure() << "reference has repeated edges";
  std::vector<std::uint32_t> to_ref(m.vertex_count(), ~0u);
  for (std::uint32_t v = 0; v < m.vertex_count(); ++v) {
    auto it = ref_vertex.find(edges[v]);
    if (it == ref_vertex.end()) return testing::AssertionFailure() << "vertex " << v << " on an edge the fresh march does not cut";
    to_ref[v] = it->second;
  }
  // Triangles as their corners in reference numbering (corner order too: both come from the same
  // case table entry of the same tetrahedron).
  std::vector<std::array<std::uint32_t, 3>> mine, theirs(ref.triangles.begin(), ref.triangles.end());
  for (const auto& t : m.triangles) mine.push_back({to_ref[t[0]], to_ref[t[1]], to_ref[t[2]]});
  std::sort(mine.begin(), mine.end());
  std::sort(theirs.begin(), theirs.end());
  if (mine != theirs) return testing::AssertionFailure() << "different triangles";
  std::vector<int> used(m.vertex_count(), 0);
  for (const auto& t : m.triangles)
    for (std::uint32_t v : t) used[v] = 1;
  for (std::size_t v = 0; v < m.vertex_count(); ++v) {
    if (!used[v]) return testing::AssertionFailure() << "vertex " << v << " unused";
    if (m.positions[v] != ref.positions[to_ref[v]] || m.normals[v] != ref.normals[to_ref[v]])
      return testing::AssertionFailure() << "vertex " << v << " differs from the fresh march";
  }
  return testing::AssertionSuccess();
}

ExtractStats extract_into(Extractor& ex, double iso, Mesh& m) {
  ExtractStats st = ex.extract(iso);
  m = ex.mesh();
  return st;
}

}  // namespace

TEST(IntervalTree, IncrementalFreshAndScanAgreeOnRandomSequences) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 60; ++trial) {
    const int levels = 2 + static_cast<int>(rng() % 6);
    TetGrid g = random_grid(rng, levels);
    const std::uint32_t depth = rng() % 7;
    IntervalTree tree = build_interval_tree(g, depth);
    ASSERT_NO_THROW(validate_interval_tree(tree, g, "test"));
    Extractor incremental(g, tree), uncached(g, tree);
    incremental.max_changed_fraction = 1.0;  // always update the previous mesh, never march afresh
    uncached.max_changed_fraction = 1.0;
    uncached.edge_cache_max_tetrahedra = 0;  // re-interpolate from the grid
    SweepState state;
    double iso = 0;
    std::vector<std::uint32_t> before;  // the active set of the previous step
    for (int step = 0; step < 40; ++step) {
      switch (rng() % 5) {
        case 0: iso = double(rng() % levels); break;                                  // exactly a vertex value
        case 1: iso += ((rng() % 2) ? 1 : -1) * 0.25; break;                           // small steps up or down
        case 2: iso = -3.0 + (rng() % 1000) * (levels + 6.0) / 1000; break;            // jumps, also outside the range
        case 3: break;                                                                 // repeat
        default: iso = std::nextafter(double(rng() % levels), (rng() % 2) ? 1e9 : -1e9);  // next to a value
      }
      sweep_to(tree, g, state, iso);
      std::vector<std::uint32_t> inc, fresh, scan;
      active_tetrahedra(tree, state, inc);
      query_active(tree, g, iso, fresh);
      scan_active(g, iso, scan);
      if (step > 0) {  // the entering entries: no repeats, and the newly active ones are those flagged 3
        ASSERT_TRUE(state.entering_complete);
        std::vector<std::uint32_t> entering = sorted(state.entering), entered, expected;
        ASSERT_EQ(std::adjacent_find(entering.begin(), entering.end()), entering.end());
        for (std::uint32_t t : entering)
          if (state.flags[t] == 3) entered.push_back(t);
        std::set_difference(scan.begin(), scan.end(), before.begin(), before.end(), std::back_inserter(expected));
        ASSERT_EQ(entered, expected) << "trial " << trial << " step " << step;
      }
      ASSERT_EQ(inc, fresh) << "trial " << trial << " step " << step << " iso " << iso;  // same order too
      ASSERT_EQ(sorted(inc), scan) << "trial " << trial << " step " << step << " iso " << iso;
      // The same active list gives bit-identical meshes, whichever way it was found.
      Mesh a, b;
      MarchScratch sa;
      march_tetrahedra(g, sorted(inc), iso, a, &sa);
      march_tetrahedra(g, scan, iso, b);
      ASSERT_EQ(a.positions, b.positions);
      ASSERT_EQ(a.triangles, b.triangles);
      // The Extractor's incrementally updated mesh is the same surface, bit for bit.
      incremental.extract(iso);
      ASSERT_EQ(incremental.last_was_incremental(), step > 0);
      ASSERT_EQ(sorted(incremental.active()), scan);
      ASSERT_TRUE(same_surface(incremental, a, sa.order)) << "trial " << trial << " step " << step;
      uncached.extract(iso);
      ASSERT_TRUE(same_surface(uncached, a, sa.order)) << "trial " << trial << " step " << step << " (no edge cache)";
      before = scan;
    }
  }
}

TEST(Extractor, StepsBetweenAValueAndItsFloatRoundingMatchFreshExtraction) {
  // The case intervals are stored as floats rounded inwards; with double values that no float
  // represents, iso-values landing between a value and its float neighbours must still re-march
  // exactly the tetrahedra whose case changed.
  std::mt19937 rng(11);
  Volume v = make_volume({7, 6, 5}, ScalarType::f64);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, 0.1 * double(rng() % 7) + 1e-9 * double(rng() % 1000));
  TetGrid g = build(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g, 3);
  Extractor ex(g, tree);
  ex.max_changed_fraction = 1.0;
  std::vector<double> isos;
  for (int k = 0; k < 12; ++k) {
    const double value = g.values[rng() % g.values.size()];
    const float f = static_cast<float>(value);
    for (double iso : {double(f), value, std::nextafter(value, 1e9), std::nextafter(value, -1e9),
                       double(std::nextafter(f, 1e9f)), double(std::nextafter(f, -1e9f)), 0.5 * (value + double(f))})
      isos.push_back(iso);
  }
  for (std::size_t step = 0; step < isos.size(); ++step) {
    ex.extract(isos[step]);
    std::vector<std::uint32_t> act;
    scan_active(g, isos[step], act);
    Mesh ref;
    MarchScratch sc;
    march_tetrahedra(g, act, isos[step], ref, &sc);
    ASSERT_EQ(ex.last_was_incremental(), step > 0);
    ASSERT_TRUE(same_surface(ex, ref, sc.order)) << step << " iso " << isos[step];
  }
}

TEST(Extractor, IncrementalStepsOnALargeGridMatchFreshExtractionForAnyThreadCount) {
  // Large enough for several blocks and chunks in the incremental update (> 32768 active
  // tetrahedra), run in arenas of 1 and 4 threads: the same history gives the same mesh, bit for
  // bit, and it is the fresh march's surface.
  Volume v = make_synthetic("marschner-lobb", 40, ScalarType::f32);
  TetGrid g = build(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g);
  Extractor one(g, tree), four(g, tree);
  one.parallel_min_triangles = four.parallel_min_triangles = 1;
  tbb::task_arena arena1(1), arena4(4);
  double iso = 0.5 * (g.source.min + g.source.max);
  const double range = g.source.max - g.source.min;
  std::size_t incremental = 0, large = 0;
  for (int step = 0; step < 12; ++step) {
    iso += (step % 3 == 2 ? -0.004 : 0.003) * range;
    ExtractStats st;
    arena1.execute([&] { one.extract(iso); });
    arena4.execute([&] { st = four.extract(iso); });
    incremental += four.last_was_incremental();
    large += four.last_was_incremental() && st.active > 2 * 16384 && st.marched > 1000;
    ASSERT_EQ(one.mesh().triangles, four.mesh().triangles) << step;
    ASSERT_EQ(one.mesh().positions, four.mesh().positions) << step;
    ASSERT_EQ(one.vertex_edges(), four.vertex_edges()) << step;
    std::vector<std::uint32_t> act;
    scan_active(g, iso, act);
    Mesh ref;
    MarchScratch sc;
    sc.parallel_min_triangles = 1;
    march_tetrahedra(g, act, iso, ref, &sc);
    ASSERT_TRUE(same_surface(four, ref, sc.order)) << step;
  }
  EXPECT_GE(incremental, 10u);
  EXPECT_GE(large, 5u);  // the multi-chunk path ran
}

TEST(IntervalTree, IsBalancedAndHoldsEachTetInItsSmallestNode) {
  Volume v = make_synthetic("marschner-lobb", 24, ScalarType::f32);
  TetGrid g = build(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g, 8);
  EXPECT_EQ(tree.depth, 8u);
  // The root's split sits at the median midpoint: each side gets at most half of the rest.
  std::uint64_t left = tree.nodes[2].begin - tree.nodes[1].begin, total = tree.entries() - tree.nodes[0].end;
  std::uint64_t right = total - left;
  EXPECT_LE(std::max(left, right), total / 2 + total / 10 + 1);
  // Smallest node: an interior node's entries straddle its split (validated); leaves go deeper than
  // no interior node could hold them. Checked by the validator, which also must refuse damage.
  EXPECT_NO_THROW(validate_interval_tree(tree, g, "t"));
  IntervalTree bad = tree;
  std::swap(bad.by_min[0], bad.by_min[bad.by_min.size() - 1]);
  EXPECT_THROW(validate_interval_tree(bad, g, "t"), InputError);
  bad = tree;
  bad.nodes[3].split += 1e9;
  EXPECT_THROW(validate_interval_tree(bad, g, "t"), InputError);
  bad = tree;
  bad.by_max.pop_back();
  EXPECT_THROW(validate_interval_tree(bad, g, "t"), InputError);
}

TEST(MarchingTets, LinearFieldGivesThePlaneWithItsNormal) {
  Volume v = make_volume({9, 8, 7}, ScalarType::f64);
  v.spacing = {0.5, 1.25, 2.0};
  const double a = 1.5, b = -0.75, c = 0.4;  // value = a x + b y + c z in physical units
  for (std::int64_t k = 0; k < 7; ++k)
    for (std::int64_t j = 0; j < 8; ++j)
      for (std::int64_t i = 0; i < 9; ++i) v.set(v.index(i, j, k), a * i * 0.5 + b * j * 1.25 + c * k * 2.0);
  TetGrid g = build(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g);
  Extractor ex(g, tree);
  Mesh m;
  const double norm = std::sqrt(a * a + b * b + c * c);
  for (double iso : {0.1234, 1.00713, 2.71828}) {  // no vertex lies exactly on these
    auto st = extract_into(ex, iso, m);
    ASSERT_GT(st.triangles, 10u);
    for (std::size_t i = 0; i < m.vertex_count(); ++i) {
      const auto& p = m.positions[i];
      EXPECT_NEAR(a * p[0] + b * p[1] + c * p[2], iso, 1e-5) << i;
      EXPECT_NEAR(m.normals[i][0], -a / norm, 1e-5);
      EXPECT_NEAR(m.normals[i][1], -b / norm, 1e-5);
      EXPECT_NEAR(m.normals[i][2], -c / norm, 1e-5);
    }
    // Triangles face their normals (counter-clockwise seen from the lower side).
    for (const auto& t : m.triangles) {
      const auto &p0 = m.positions[t[0]], &p1 = m.positions[t[1]], &p2 = m.positions[t[2]];
      double u[3], w[3];
      for (int k = 0; k < 3; ++k) u[k] = double(p1[k]) - p0[k], w[k] = double(p2[k]) - p0[k];
      double n[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
      EXPECT_LT(n[0] * a + n[1] * b + n[2] * c, 0);
    }
    auto topo = topology(m, g.source);
    EXPECT_EQ(topo.nonmanifold, 0u);
    EXPECT_EQ(topo.misoriented, 0u);
    EXPECT_EQ(topo.euler, 1);  // a disc
  }
}

TEST(MarchingTets, SphereIsClosedOrientedAndConverges) {
  double prev_err = 1e9;
  for (int n : {16, 28, 40}) {  // full grids: the reconstruction error shrinks with the voxel size
    Volume v = make_synthetic("sphere", n, ScalarType::f32);
    TetGrid g = build(v, all_voxels(v));
    IntervalTree tree = build_interval_tree(g);
    Extractor ex(g, tree);
    Mesh m;
    const double iso = 700;  // outside the core: value 1000 R / r, so r = R · 1000 / 700
    extract_into(ex, iso, m);
    auto topo = topology(m, g.source);
    EXPECT_EQ(topo.boundary, 0u) << n;
    EXPECT_EQ(topo.nonmanifold, 0u) << n;
    EXPECT_EQ(topo.misoriented, 0u) << n;
    EXPECT_EQ(topo.degenerate, 0u) << n;
    EXPECT_EQ(topo.euler, 2) << n;
    // The sphere's centre and radius as the generator defines them (voxel units, spacing 1).
    const double R = n / 4.0, r = R * 1000.0 / iso, c = (n - 1) / 2.0;
    const double vol = mesh_volume(m), area = mesh_area(m);
    EXPECT_GT(vol, 0) << "outward orientation gives a positive enclosed volume";
    std::size_t outward = 0;
    for (std::size_t i = 0; i < m.vertex_count(); ++i) {
      const auto& p = m.positions[i];
      const auto& q = m.normals[i];
      outward += (p[0] - c) * q[0] + (p[1] - c) * q[1] + (p[2] - c) * q[2] > 0;
    }
    EXPECT_EQ(outward, m.vertex_count()) << n;
    const double err = std::abs(vol / (4.0 / 3.0 * M_PI * r * r * r) - 1) + std::abs(area / (4 * M_PI * r * r) - 1);
    EXPECT_LT(err, prev_err) << n;
    prev_err = err;
  }
  EXPECT_LT(prev_err, 0.03);
}

TEST(MarchingTets, RandomGridsAreWatertightInsideTheBoxWithoutDegenerateTriangles) {
  std::mt19937 rng(17);
  std::size_t meshes = 0;
  for (int trial = 0; trial < 80; ++trial) {
    TetGrid g = random_grid(rng, 2 + static_cast<int>(rng() % 5));
    IntervalTree tree = build_interval_tree(g, rng() % 6);
    Extractor ex(g, tree);
    Mesh m;
    for (int q = 0; q < 6; ++q) {
      // Half of the iso-values equal vertex values exactly: the tie rule must keep the mesh clean.
      double iso = (q % 2) ? double(rng() % 5) : (rng() % 1000) / 200.0;
      extract_into(ex, iso, m);
      if (m.triangles.empty()) continue;
      ++meshes;
      auto topo = topology(m, g.source);
      ASSERT_TRUE(topo.boundary_on_box) << "trial " << trial << " iso " << iso;
      ASSERT_EQ(topo.nonmanifold, 0u) << "trial " << trial << " iso " << iso;
      ASSERT_EQ(topo.misoriented, 0u) << "trial " << trial << " iso " << iso;
      for (const auto& t : m.triangles) ASSERT_GT(triangle_area(m, t), 0) << "trial " << trial << " iso " << iso;
    }
  }
  EXPECT_GT(meshes, 200u);
}

TEST(MarchingTets, ParallelNumberingEqualsSequentialFirstUse) {
  Volume v = make_synthetic("marschner-lobb", 20, ScalarType::f32);
  TetGrid g = build(v, all_voxels(v));
  std::vector<std::uint32_t> act;
  const double iso = 0.5 * (g.source.min + g.source.max);
  scan_active(g, iso, act);
  Mesh one, many;
  MarchScratch s1, s2;
  s1.parallel_min_triangles = ~std::size_t{0};
  s2.parallel_min_triangles = 1;
  march_tetrahedra(g, act, iso, one, &s1);
  for (int run = 0; run < 3; ++run) {
    march_tetrahedra(g, act, iso, many, &s2);
    ASSERT_EQ(one.triangles, many.triangles);
    ASSERT_EQ(one.positions, many.positions);
  }
  // First-use order: scanning the corners, each new vertex is the next id.
  std::uint32_t next = 0;
  for (const auto& t : one.triangles)
    for (auto id : t) {
      ASSERT_LE(id, next);
      if (id == next) ++next;
    }
  EXPECT_EQ(next, one.vertex_count());
  // Distinct cut edges give distinct points.
  std::set<std::array<float, 3>> pts(one.positions.begin(), one.positions.end());
  EXPECT_EQ(pts.size(), one.vertex_count());
}

TEST(MarchingTets, OutsideTheRangeGivesAnEmptyMesh) {
  Volume v = make_synthetic("sphere", 16, ScalarType::i16);
  TetGrid g = build(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g);
  Extractor ex(g, tree);
  Mesh m;
  auto st = extract_into(ex, g.source.max + 1, m);
  EXPECT_FALSE(st.in_range);
  EXPECT_EQ(st.triangles, 0u);
  st = extract_into(ex, g.source.min, m);  // everything is at or above the minimum: nothing below
  EXPECT_EQ(st.triangles, 0u);
  EXPECT_THROW(extract_into(ex, std::nan(""), m), InputError);
}

TEST(MeshFiles, PlyRoundTripAndOtherFormats) {
  testutil::TempDir t("mesh");
  Volume v = make_synthetic("sphere", 20, ScalarType::i16);
  TetGrid g = build(v, all_voxels(v));
  IntervalTree tree = build_interval_tree(g);
  Extractor ex(g, tree);
  Mesh m;
  extract_into(ex, 600, m);
  ASSERT_GT(m.triangle_count(), 100u);
  write_mesh(m, t / "a.ply");
  Mesh r = read_ply(t / "a.ply");
  EXPECT_EQ(r.positions, m.positions);
  EXPECT_EQ(r.normals, m.normals);
  EXPECT_EQ(r.triangles, m.triangles);
  write_mesh(m, t / "a.stl");
  EXPECT_EQ(std::filesystem::file_size(t / "a.stl"), 84 + 50 * m.triangle_count());
  write_mesh(m, t / "a.obj");
  std::ifstream obj(t / "a.obj");
  std::size_t v_lines = 0, f_lines = 0;
  for (std::string line; std::getline(obj, line);) {
    v_lines += line.rfind("v ", 0) == 0;
    f_lines += line.rfind("f ", 0) == 0;
  }
  EXPECT_EQ(v_lines, m.vertex_count());
  EXPECT_EQ(f_lines, m.triangle_count());
  write_mesh(m, t / "a.glb");
  const std::string bytes = testutil::read_bytes(t / "a.glb");
  ASSERT_GT(bytes.size(), 20u);
  EXPECT_EQ(bytes.substr(0, 4), "glTF");
  std::uint32_t total, json_len;
  std::memcpy(&total, bytes.data() + 8, 4);
  std::memcpy(&json_len, bytes.data() + 12, 4);
  EXPECT_EQ(total, bytes.size());
  auto j = nlohmann::json::parse(bytes.substr(20, json_len));
  EXPECT_EQ(j["accessors"][0]["count"], m.vertex_count());
  EXPECT_EQ(j["accessors"][2]["count"], 3 * m.triangle_count());
  EXPECT_THROW(write_mesh(m, t / "a.xyz"), InputError);
  // A damaged PLY is refused.
  const std::string ply = testutil::read_bytes(t / "a.ply");
  testutil::write_bytes(t / "cut.ply", ply.substr(0, ply.size() / 2));
  EXPECT_THROW(read_ply(t / "cut.ply"), InputError);
}

TEST(ExtractCli, RunExtractSeveralIsoValuesAndBadInput) {
  testutil::TempDir t("extract");
  ASSERT_EQ(testutil::run_cli("generate sphere --size 50 -o " + (t / "s.nrrd")).code, 0);
  auto r = testutil::run_cli("run " + (t / "s.nrrd") + " --relative --max-error 0.15 --iso 0.7 --json -o " + (t / "s.ply") +
                             " --save-grid " + (t / "s.adg"));
  ASSERT_EQ(r.code, 0) << r.err;
  auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["surfaces"].size(), 1u);
  const nlohmann::json s0 = j["surfaces"][0];
  for (const char* k : {"iso", "triangles", "vertices", "active_tetrahedra", "seconds"}) EXPECT_TRUE(s0.contains(k)) << k;
  Mesh m = read_ply(t / "s.ply");
  EXPECT_EQ(m.triangle_count(), s0["triangles"].get<std::size_t>());
  EXPECT_EQ(topology(m, GridSource{}).boundary, 0u);

  r = testutil::run_cli("extract " + (t / "s.adg") + " --relative --iso 0.7,0.72,2 --json -o " + (t / "m.obj"));
  ASSERT_EQ(r.code, 0) << r.err;
  j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["surfaces"].size(), 3u);
  EXPECT_EQ(j["surfaces"][0]["triangles"], s0["triangles"]);  // same grid, same iso: same surface
  EXPECT_TRUE(std::filesystem::exists(t / "m-0.7.obj"));
  EXPECT_TRUE(std::filesystem::exists(t / "m-0.72.obj"));
  EXPECT_FALSE(j["surfaces"][2]["in_range"].get<bool>());
  EXPECT_EQ(j["surfaces"][2]["triangles"], 0);
  r = testutil::run_cli("extract " + (t / "s.adg") + " --iso 900 -o " + (t / "m.ply"));
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("triangles"), std::string::npos);

  for (std::string bad : {"extract " + (t / "s.adg") + " --iso abc -o " + (t / "x.ply"),
                          "extract " + (t / "s.adg") + " --iso 1 -o " + (t / "x.txt"),
                          "extract " + (t / "s.nrrd") + " --iso 1 -o " + (t / "x.ply"),
                          "extract " + (t / "missing.adg") + " --iso 1 -o " + (t / "x.ply"),
                          "run " + (t / "s.nrrd") + " --iso nan -o " + (t / "x.ply")}) {
    auto b = testutil::run_cli(bad);
    EXPECT_EQ(b.code, 2) << bad;
    EXPECT_EQ(std::count(b.err.begin(), b.err.end(), '\n'), 1) << bad << ": " << b.err;
    EXPECT_FALSE(std::filesystem::exists(t / "x.ply"));
  }
}
