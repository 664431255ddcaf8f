// Grid files that lie: a checksum that matches says nothing about what the file says. Each test
// builds its lying files from a grid prepared here (no committed binaries), with the checksum made
// to match (save_grid, or GridSections::assemble), and is named after what broke before the loader
// checked it (issue 41): crashes and over-reads in the hierarchy's walks, and silent wrong
// surfaces. The last test is the differential check: any grid that loads gives the surfaces of
// preparing its own volume. The files keep their index (save_grid's with_index, as every file
// before version 6 did): a lie in it must be refused too.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <numeric>
#include <random>
#include <set>
#include <thread>

#include "adaptiso/bisection.hpp"
#include "adaptiso/error.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/synthetic.hpp"
#include "grid/diamond.hpp"
#include "grid/thread_transport.hpp"
#include "grid/traversal.hpp"
#include "io/grid_file_sections.hpp"
#include "test_util.hpp"

using namespace adaptiso;
using detail::GridSections;

namespace {

// On the volume's own lattice: these lies are told about its vertices and codes (a padded
// lattice's volume_dims have their own, MetadataOutsideItsSaneRangeIsRefused).
PreparedGrid bisection(const Volume& v, double relative_error, double displacement = 0) {
  PrepareOptions o;
  o.max_error = relative_error;
  o.relative = true;
  o.max_displacement = displacement;
  o.pad_lattice = false;
  return prepare(v, o);
}
PreparedGrid delaunay(const Volume& v, double relative_error) {
  PrepareOptions o;
  o.grid = GridKind::delaunay;
  o.max_error = relative_error;
  o.relative = true;
  return prepare(v, o);
}

// A smooth field with some noise on a box that is no power-of-two cube, so diamonds cross its far
// faces and are always split.
Volume bumpy(Dims d, unsigned seed) {
  std::mt19937 rng(seed);
  Volume v = make_volume(d, ScalarType::f32);
  for (std::int64_t z = 0; z < d[2]; ++z)
    for (std::int64_t y = 0; y < d[1]; ++y)
      for (std::int64_t x = 0; x < d[0]; ++x)
        v.set(v.index(x, y, z), std::sin(0.5 * x) * std::cos(0.4 * y) + 0.1 * z + 0.05 * double(rng() % 8));
  return v;
}

// The message of the InputError that loading `path` throws ("" when it loads).
std::string refusal(const std::string& path) {
  try {
    load_grid(path);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// load_grid_shared by threads playing processes, process p loading paths[p]: each one's grid, or
// the message of what it threw ("" when it loaded). `held_open`: through an OpenGridFile opened
// and loaded with the transport instead (Python's lazy route).
struct SharedLoad {
  std::vector<std::optional<PreparedGrid>> grids;
  std::vector<std::string> refusals;
};
SharedLoad load_shared(const std::vector<std::string>& paths, GridParts parts = GridParts::all, bool held_open = false) {
  const int processes = static_cast<int>(paths.size());
  testutil::Hub hub;
  SharedLoad out{std::vector<std::optional<PreparedGrid>>(paths.size()), std::vector<std::string>(paths.size())};
  testutil::as_processes(hub, processes, [&](ShareTransport& t, int p) {
    try {
      const std::string& path = paths[static_cast<std::size_t>(p)];
      out.grids[static_cast<std::size_t>(p)] = held_open ? OpenGridFile(path, &t).load(parts, {}, &t) : load_grid_shared(path, parts, t);
    } catch (const InputError& e) {
      out.refusals[static_cast<std::size_t>(p)] = e.what();
    } catch (const std::exception& e) {  // a process left waiting: not the refusal every process must give
      out.refusals[static_cast<std::size_t>(p)] = std::string("not an InputError: ") + e.what();
    }
  });
  EXPECT_EQ(hub.left(), 0u) << "messages sent that nobody received";
  return out;
}

// Expects the file refused with a message naming it and holding `fragment`, on one line; and
// refused alike, word for word, by every process of a load shared over 2 and 3 (load_grid_shared:
// the lie may fall in any process's share of the checks).
void expect_refused(const std::string& path, const std::string& fragment, const std::string& what = "") {
  const std::string m = refusal(path);
  ASSERT_FALSE(m.empty()) << what << ": loaded";
  EXPECT_NE(m.find(path), std::string::npos) << m;
  EXPECT_NE(m.find(fragment), std::string::npos) << what << ": " << m;
  EXPECT_EQ(m.find('\n'), std::string::npos) << m;
  for (int processes : {2, 3}) {
    const SharedLoad shared = load_shared(std::vector<std::string>(static_cast<std::size_t>(processes), path));
    for (int p = 0; p < processes; ++p)
      EXPECT_EQ(shared.refusals[static_cast<std::size_t>(p)], m) << what << ": process " << p << " of " << processes;
  }
}

void save_sections(const GridSections& s, const std::string& path) { testutil::write_bytes(path, s.assemble()); }
GridSections sections_of(const std::string& path) {
  auto s = GridSections::parse(testutil::read_bytes(path));
  EXPECT_TRUE(s);
  return *s;
}

// The grid without vertex `gone`, its tetrahedra re-pointed to `instead`, with a fresh index: a
// file that is consistent in everything but its hierarchy.
void remove_vertex(PreparedGrid& p, std::uint32_t gone, std::uint32_t instead) {
  TetGrid& g = p.grid;
  auto erase = [&](auto& a) { a.erase(a.begin() + gone); };
  erase(g.ijk);
  erase(g.values);
  erase(g.gradients);
  erase(p.hierarchy->error_code);
  if (!p.hierarchy->displacement_code.empty()) erase(p.hierarchy->displacement_code);
  erase(p.hierarchy->value_span);
  for (auto& t : g.tets)
    for (auto& v : t) {
      if (v == gone) v = instead;
      if (v > gone) --v;
    }
  p.index = build_interval_tree(g, p.index.depth);
}

// Edits the metadata's "source" object of a saved grid.
template <class Edit>
void edit_source(const std::string& from, const std::string& to, Edit edit) {
  GridSections s = sections_of(from);
  auto j = nlohmann::json::parse(s.meta);
  edit(j["source"]);
  s.meta = j.dump();
  save_sections(s, to);
}

std::uint32_t vertex_at(const TetGrid& g, std::uint32_t x, std::uint32_t y, std::uint32_t z) {
  const auto it = std::find(g.ijk.begin(), g.ijk.end(), std::array<std::uint32_t, 3>{x, y, z});
  EXPECT_NE(it, g.ijk.end());
  return static_cast<std::uint32_t>(it - g.ijk.begin());
}

using Corner = std::array<float, 3>;
using Triangle = std::array<Corner, 3>;

std::vector<Triangle> triangles_of(const Mesh& m) { return testutil::sorted_triangles(m); }

}  // namespace

// Issue 41, item 1: 0 vertices, 0 tetrahedra, flags saying bisection, dims 17³ (an empty
// section's CRC is 0): it loaded, then extract --max-error, view and Python segfaulted.
TEST(GridFileLies, EmptyGridClaimingAHierarchyIsRefused) {
  testutil::TempDir t("lies_empty");
  save_grid(bisection(make_synthetic("sphere", 17, ScalarType::f32), 0.05), t / "g.adg", true);
  GridSections s = sections_of(t / "g.adg");
  for (auto [section, bytes] : s.vertex_sections()) section->clear();
  s.tets.clear();
  s.by_min.clear();
  s.by_max.clear();
  s.depth = 0;
  s.nodes.assign(24, '\0');
  ASSERT_EQ(s.flags & GridSections::kHasHierarchy, GridSections::kHasHierarchy);
  save_sections(s, t / "empty.adg");
  expect_refused(t / "empty.adg", "no tetrahedra");
}

// Issue 41, item 1: a root-cube corner removed and its tetrahedra re-pointed read past a heap
// buffer in the hierarchy's walk and in bisection_coarsen, and gave a wrong surface with exit 0.
TEST(GridFileLies, RootCornerRemovedWithItsTetrahedraRepointedIsRefused) {
  testutil::TempDir t("lies_corner");
  const PreparedGrid fine = bisection(make_synthetic("marschner-lobb", 17, ScalarType::f32), 0.02);
  for (auto c : {std::array<std::uint32_t, 3>{0, 0, 0}, {16, 0, 0}, {16, 16, 16}, {0, 16, 16}}) {
    PreparedGrid p = fine;
    const std::uint32_t v = vertex_at(p.grid, c[0], c[1], c[2]);
    remove_vertex(p, v, v == 0 ? 1 : v - 1);
    save_grid(p, t / "g.adg", true);
    expect_refused(t / "g.adg", "root cube's corner", fmt::format("{},{},{}", c[0], c[1], c[2]));
    // The same grid in memory, never through a file: bisection_coarsen refuses it too.
    BisectionOptions o;
    o.max_error = 1;
    EXPECT_THROW(bisection_coarsen(p.grid, *p.hierarchy, o), InputError);
  }
}

// Issue 41, item 1: 13 of 20 random removals of a tetrahedron's corner did the same.
TEST(GridFileLies, RandomVertexRemovalsWithTheirTetrahedraRepointedAreRefused) {
  testutil::TempDir t("lies_removal");
  const PreparedGrid fine = bisection(bumpy({13, 10, 7}, 3), 0.02);
  std::mt19937 rng(41);
  for (int trial = 0; trial < 20; ++trial) {
    PreparedGrid p = fine;
    const auto gone = static_cast<std::uint32_t>(rng() % p.grid.vertex_count());
    remove_vertex(p, gone, gone == 0 ? 1 : gone - 1);
    save_grid(p, t / "g.adg", true);
    expect_refused(t / "g.adg", "grid", fmt::format("vertex {}", gone));
  }
}

// Issue 41, item 2: every per-vertex array permuted alike and the tetrahedra re-pointed gave 0
// triangles with "error_bound": 0.
TEST(GridFileLies, ConsistentlyPermutedVertexOrderIsRefused) {
  testutil::TempDir t("lies_permuted");
  PreparedGrid p = bisection(make_synthetic("sphere", 17, ScalarType::i16), 0.02);
  const std::size_t n = p.grid.vertex_count();
  std::vector<std::uint32_t> order(n), renumber(n);
  std::iota(order.begin(), order.end(), 0u);
  std::shuffle(order.begin(), order.end(), std::mt19937(7));
  for (std::uint32_t i = 0; i < n; ++i) renumber[order[i]] = i;
  auto permute = [&](auto& a) {
    auto b = a;
    for (std::size_t i = 0; i < n; ++i) b[i] = a[order[i]];
    a = std::move(b);
  };
  permute(p.grid.ijk);
  permute(p.grid.values);
  permute(p.grid.gradients);
  permute(p.hierarchy->error_code);
  permute(p.hierarchy->value_span);
  for (auto& tet : p.grid.tets)
    for (auto& v : tet) v = renumber[v];
  p.index = build_interval_tree(p.grid, p.index.depth);
  save_grid(p, t / "g.adg", true);
  expect_refused(t / "g.adg", "ascending voxel order");
}

// Issue 41, item 2: metadata outside any sane range was accepted: spacing 1e308 (infinite
// coordinates), 5e-324, origin ±1e308, an all-zero direction, min > max, 4 entries in dims, any
// type string. Each must be refused naming what is wrong.
TEST(GridFileLies, MetadataOutsideItsSaneRangeIsRefused) {
  testutil::TempDir t("lies_meta");
  save_grid(bisection(make_synthetic("sphere", 9, ScalarType::i16), 0.02), t / "g.adg", true);
  ASSERT_EQ(refusal(t / "g.adg"), "");
  struct Case {
    const char* name;
    std::function<void(nlohmann::json&)> edit;
    const char* fragment;
  };
  const std::vector<Case> cases = {
      {"spacing 1e308", [](auto& s) { s["spacing"][0] = 1e308; }, "spacing"},
      {"spacing 5e-324", [](auto& s) { s["spacing"][1] = 5e-324; }, "spacing"},
      {"spacing 0", [](auto& s) { s["spacing"][2] = 0.0; }, "spacing"},
      {"origin 1e308", [](auto& s) { s["origin"][0] = 1e308; }, "origin"},
      {"origin -1e308", [](auto& s) { s["origin"][2] = -1e308; }, "origin"},
      {"origin within range, box beyond it", [](auto& s) { s["origin"][0] = 0.9e30, s["spacing"][0] = 1e29; }, "box reaches"},
      {"all-zero direction", [](auto& s) { s["direction"] = std::vector<double>(9, 0.0); }, "not orthonormal"},
      {"sheared direction", [](auto& s) { s["direction"][1] = 0.5; }, "not orthonormal"},
      {"8 entries in direction", [](auto& s) { s["direction"].erase(8); }, "direction"},
      {"min > max", [](auto& s) { std::swap(s["min"], s["max"]); }, "min exceeds max"},
      {"4 entries in dims", [](auto& s) { s["dims"].push_back(9); }, "dims"},
      {"fractional dims", [](auto& s) { s["dims"][0] = 9.5; }, "dims"},
      {"dims 1", [](auto& s) { s["dims"][0] = 1; }, "dims"},
      {"dims whose product overflows 64 bits",
       [](auto& s) {
         s["dims"] = {1073741825, 1073741825, 1073741825};
       },
       "more voxels"},
      {"type string quaternion", [](auto& s) { s["type"] = "quaternion"; }, "element type"},
      {"type string int", [](auto& s) { s["type"] = "int"; }, "element type"},
      {"negative max_error", [](auto& s) { s["max_error"] = -1.0; }, "max_error"},
      {"max_error a string", [](auto& s) { s["max_error"] = "1"; }, "max_error"},
      {"no min", [](auto& s) { s.erase("min"); }, "min"},
      {"volume_dims past the lattice's dims",
       [](auto& s) {
         s["volume_dims"] = {10, 9, 9};
       },
       "volume_dims"},
      {"volume_dims 1",
       [](auto& s) {
         s["volume_dims"] = {1, 9, 9};
       },
       "volume_dims"},
      {"volume_dims of 2 entries",
       [](auto& s) {
         s["volume_dims"] = {9, 9};
       },
       "volume_dims"},
      {"volume_dims a string", [](auto& s) { s["volume_dims"] = "9"; }, "volume_dims"},
  };
  for (const auto& c : cases) {
    edit_source(t / "g.adg", t / "m.adg", c.edit);
    expect_refused(t / "m.adg", c.fragment, c.name);
  }
}

// Found by fuzz_grid_structure: the statistics' counts were converted from any JSON number, and a
// float of 2.13e64 converted to an unsigned count is undefined behaviour (UBSan stopped there). They
// are informational: a count that is no whole number in range is left out, the grid loads.
TEST(GridFileLies, StatisticsWithAHugeFloatCountAreLeftOutNotConverted) {
  testutil::TempDir t("lies_stats");
  save_grid(bisection(make_synthetic("sphere", 9, ScalarType::i16), 0.02), t / "g.adg", true);
  GridSections s = sections_of(t / "g.adg");
  auto j = nlohmann::json::parse(s.meta);
  j["prepare"]["kept"] = 2.13e64;
  j["prepare"]["tetrahedra"] = -5;
  j["prepare"]["index_depth"] = 1e10;
  s.meta = j.dump();
  save_sections(s, t / "m.adg");
  const PreparedGrid p = load_grid(t / "m.adg");
  EXPECT_EQ(p.stats.kept, 0u);
  EXPECT_EQ(p.stats.tetrahedra, 0u);
  EXPECT_EQ(p.stats.index_depth, p.index.depth);  // the index's own, whatever the metadata says
}

// The hierarchy must be the one its own codes select: issue 41's "33 of 295 accepted mutants
// change the --max-error surface". Each lie here kept the checksum and the file's layout.
TEST(GridFileLies, HierarchyThatIsNotItsCodesSelectionIsRefused) {
  testutil::TempDir t("lies_hierarchy");
  const PreparedGrid fine = bisection(bumpy({13, 10, 7}, 5), 0.02, 0.5);
  ASSERT_FALSE(fine.hierarchy->displacement_code.empty());
  save_grid(fine, t / "g.adg", true);
  ASSERT_EQ(refusal(t / "g.adg"), "");
  const auto& h = *fine.hierarchy;
  const TetGrid& g = fine.grid;
  const detail::Lattice lat = detail::make_lattice(g.source.dims);
  std::set<std::array<std::uint32_t, 3>> vertices(g.ijk.begin(), g.ijk.end());
  auto is_vertex = [&](const detail::Coord& c) {
    return lat.in_box(c) && vertices.count({std::uint32_t(c[0]), std::uint32_t(c[1]), std::uint32_t(c[2])});
  };
  // Vertices to lie about, whose diamonds have no split children (so the lie is theirs alone): one
  // across the far faces (always split), one deep inside split by its error alone, its parents'
  // codes below 254.
  std::uint32_t forced = 0, inner = 0;
  for (std::uint32_t v = 0; v < g.vertex_count(); ++v) {
    const detail::Coord c{std::int32_t(g.ijk[v][0]), std::int32_t(g.ijk[v][1]), std::int32_t(g.ijk[v][2])};
    const detail::Diamond d = detail::classify(c, lat.k);
    if (!d.valid) continue;
    detail::Coord kids[8], parents[4];
    const int nk = detail::children(d, lat.S, kids), np = detail::parents(d, lat.S, parents);
    if (std::any_of(kids, kids + nk, is_vertex)) continue;
    if (!forced && detail::placement(d, lat).forced) forced = v;
    bool low_parents = true;
    for (int i = 0; i < np; ++i)
      if (is_vertex(parents[i]) &&
          h.error_code[vertex_at(g, std::uint32_t(parents[i][0]), std::uint32_t(parents[i][1]), std::uint32_t(parents[i][2]))] >= 254)
        low_parents = false;
    if (!inner && low_parents && detail::deep_inside(d, lat) && h.error_code[v] > h.error_threshold + 2 &&
        h.displacement_code[v] <= h.displacement_threshold && h.error_code[v] < 250)
      inner = v;
  }
  ASSERT_TRUE(forced && inner);
  // A value that makes the inner vertex's deviation from its refinement edge twice its code's
  // error, towards the middle of the value range.
  const double deviation = [&] {
    const detail::Coord c{std::int32_t(g.ijk[inner][0]), std::int32_t(g.ijk[inner][1]), std::int32_t(g.ijk[inner][2])};
    const auto [a, b] = detail::refinement_edge(detail::classify(c, lat.k));
    const double mid = 0.5 * (g.values[vertex_at(g, std::uint32_t(a[0]), std::uint32_t(a[1]), std::uint32_t(a[2]))] +
                              g.values[vertex_at(g, std::uint32_t(b[0]), std::uint32_t(b[1]), std::uint32_t(b[2]))]);
    const double e = 2 * h.codes.error(h.error_code[inner]);
    return mid < 0.5 * (g.source.min + g.source.max) ? mid + e : mid - e;
  }();
  ASSERT_GE(deviation, g.source.min);
  ASSERT_LE(deviation, g.source.max);
  struct Case {
    const char* name;
    std::function<void(PreparedGrid&)> lie;
    const char* fragment;
  };
  const std::vector<Case> cases = {
      {"a vertex whose codes do not split it", [&](PreparedGrid& p) { p.hierarchy->error_code[inner] = h.error_threshold; },
       "does not split"},
      {"a diamond across the box not always split", [&](PreparedGrid& p) { p.hierarchy->error_code[forced] = 200; }, "always split"},
      {"a code above its parent's", [&](PreparedGrid& p) { p.hierarchy->error_code[inner] = 254; }, "parent"},
      {"a code below its own deviation", [&](PreparedGrid& p) { p.grid.values[inner] = deviation; }, "deviation"},
      {"the error threshold", [&](PreparedGrid& p) { p.hierarchy->error_threshold += 1; }, "error threshold"},
      {"the displacement threshold", [&](PreparedGrid& p) { p.hierarchy->displacement_threshold += 1; }, "displacement threshold"},
      {"the error scale", [&](PreparedGrid& p) { p.hierarchy->codes.scale *= 2; }, "scale"},
      {"the root cube", [&](PreparedGrid& p) { p.hierarchy->root_size *= 2; }, "root cube"},
      {"a value span narrowed",
       [&](PreparedGrid& p) { p.hierarchy->value_span[inner][1] = std::nextafter(p.hierarchy->value_span[inner][1], -1e30f); },
       "value span"},
      {"a value span widened", [&](PreparedGrid& p) { p.hierarchy->value_span[inner][0] -= 1; }, "value span"},
      {"two value spans swapped", [&](PreparedGrid& p) { std::swap(p.hierarchy->value_span[inner], p.hierarchy->value_span[forced]); },
       "value span"},
      {"two tetrahedra swapped", [&](PreparedGrid& p) { std::swap(p.grid.tets[3], p.grid.tets[p.grid.tet_count() - 4]); }, "leaves"},
      {"a tetrahedron's corners swapped", [&](PreparedGrid& p) { std::swap(p.grid.tets[5][1], p.grid.tets[5][2]); }, "leaves"},
      {"a tetrahedron dropped", [&](PreparedGrid& p) { p.grid.tets.pop_back(); }, "leaves"},
      {"the method", [&](PreparedGrid& p) { p.grid.source.method = "reconstruction"; }, "bisection hierarchy"},
      {"no max_displacement beside displacement codes", [&](PreparedGrid& p) { p.stats.max_displacement = 0; }, "displacement threshold"},
  };
  for (const auto& c : cases) {
    PreparedGrid p = fine;
    c.lie(p);
    p.index = build_interval_tree(p.grid, p.index.depth);
    save_grid(p, t / "l.adg", true);
    expect_refused(t / "l.adg", c.fragment, c.name);
  }
}

// Grids without a hierarchy (Delaunay, floored levels): their tetrahedra must tile the box.
TEST(GridFileLies, TetrahedraThatDoNotTileTheBoxAreRefused) {
  testutil::TempDir t("lies_tiling");
  const PreparedGrid fine = delaunay(make_synthetic("sphere", 11, ScalarType::f32), 0.05);
  save_grid(fine, t / "g.adg", true);
  ASSERT_EQ(refusal(t / "g.adg"), "");
  struct Case {
    const char* name;
    std::function<void(PreparedGrid&)> lie;
    const char* fragment;
  };
  const std::vector<Case> cases = {
      {"an inverted tetrahedron", [](PreparedGrid& p) { std::swap(p.grid.tets[0][0], p.grid.tets[0][1]); }, "positively oriented"},
      {"a tetrahedron dropped", [](PreparedGrid& p) { p.grid.tets.erase(p.grid.tets.begin() + 2); }, "do not tile"},
      {"a tetrahedron repeated", [](PreparedGrid& p) { p.grid.tets.push_back(p.grid.tets[1]); }, "do not tile"},
      {"a vertex no tetrahedron uses",
       [](PreparedGrid& p) {
         // The first voxel that is no vertex, inserted in its place in the voxel order.
         auto& g = p.grid;
         const auto& d = g.source.dims;
         auto key = [&](const std::array<std::uint32_t, 3>& c) { return c[0] + d[0] * (c[1] + d[1] * c[2]); };
         std::size_t at = 0;
         std::int64_t voxel = 0;
         while (at < g.vertex_count() && key(g.ijk[at]) == voxel) ++at, ++voxel;
         ASSERT_LT(at, g.vertex_count());
         g.ijk.insert(g.ijk.begin() + static_cast<long>(at),
                      std::array<std::uint32_t, 3>{std::uint32_t(voxel % d[0]), std::uint32_t(voxel / d[0] % d[1]),
                                                   std::uint32_t(voxel / d[0] / d[1])});
         g.values.insert(g.values.begin() + static_cast<long>(at), g.values[at]);
         g.gradients.insert(g.gradients.begin() + static_cast<long>(at), g.gradients[at]);
         for (auto& tet : g.tets)
           for (auto& x : tet) x += x >= at ? 1 : 0;
       },
       "no corner of any tetrahedron"},
      {"a repeated vertex",
       [](PreparedGrid& p) {
         auto& g = p.grid;
         g.ijk.insert(g.ijk.begin() + 3, g.ijk[3]);
         g.values.insert(g.values.begin() + 3, g.values[3]);
         g.gradients.insert(g.gradients.begin() + 3, g.gradients[3]);
         for (auto& tet : g.tets)
           for (auto& x : tet) x += x > 3 ? 1 : 0;
       },
       "ascending voxel order"},
      {"a value outside the range", [](PreparedGrid& p) { p.grid.values[4] = p.grid.source.max + 1; }, "value range"},
      {"a gradient that is not a number", [](PreparedGrid& p) { p.grid.gradients[4][1] = std::nanf(""); }, "gradient"},
  };
  for (const auto& c : cases) {
    PreparedGrid p = fine;
    c.lie(p);
    p.index = build_interval_tree(p.grid, p.index.depth);
    save_grid(p, t / "l.adg", true);
    expect_refused(t / "l.adg", c.fragment, c.name);
  }
}

// Issue 41, item 2's differential check: any grid that loads gives the same --max-error surfaces
// as preparing its own volume (the source's voxels, under the geometry the file gives them), or is
// refused. The mutants are GridSections' structural ones (what the fuzz target fuzz_grid_structure
// makes), 1 to 3 a file; mutants of the data itself (values, codes) describe another volume and
// are left to the fuzz target. Surfaces compared by their triangles' positions (normals come from
// the gradients, data too).
TEST(GridFileLies, AnyMutantThatLoadsGivesTheSurfaceOfPreparingItsOwnVolume) {
  testutil::TempDir t("lies_differential");
  struct Source {
    Volume volume;
    double error, displacement;
  };
  std::vector<Source> sources;
  sources.push_back({make_synthetic("marschner-lobb", 17, ScalarType::f32), 0.01, 0});
  sources.push_back({bumpy({13, 10, 7}, 9), 0.0, 0});
  sources.push_back({make_synthetic("sphere", 12, ScalarType::i16), 0.02, 0.5});
  std::mt19937_64 rng(2041);
  int loaded = 0, refused = 0, compared = 0;
  for (std::size_t si = 0; si < sources.size(); ++si) {
    const Source& src = sources[si];
    const ValueRange r = value_range(src.volume);
    const PreparedGrid fine = bisection(src.volume, src.error, src.displacement);
    save_grid(fine, t / "g.adg", true);
    const std::string original = testutil::read_bytes(t / "g.adg");
    for (int m = 0; m < 250; ++m) {
      auto s = GridSections::parse(original);
      ASSERT_TRUE(s);
      std::string kinds;
      for (int n = m == 0 ? 0 : 1 + static_cast<int>(rng() % 3); n > 0; --n)
        kinds += std::string(detail::mutate_sections(*s, rng, false)) + "; ";
      testutil::write_bytes(t / "m.adg", s->assemble());
      std::shared_ptr<const PreparedGrid> grid;
      try {
        grid = std::make_shared<const PreparedGrid>(load_grid(t / "m.adg"));
      } catch (const InputError&) {
        ++refused;
        continue;
      }
      ++loaded;
      const GridSource& g = grid->grid.source;
      ASSERT_EQ(g.dims, src.volume.dims) << "a grid of other dimensions loaded: " << kinds;
      Volume own = src.volume;  // its voxels, the file's geometry
      own.spacing = g.spacing;
      own.origin = g.origin;
      own.direction = g.direction;
      // The error it was prepared at, from the source (a file without its hierarchy keeps no code).
      const double prepared_error = fine.hierarchy->codes.error(fine.hierarchy->error_threshold);
      // Without --max-error: the file's own tetrahedra.
      const double mid = r.min + 0.5 * (r.max - r.min);
      Extractor mine(grid);
      mine.extract(mid);
      PrepareOptions o;
      o.max_error = prepared_error;
      o.max_displacement = src.displacement;
      o.pad_lattice = false;  // as bisection() made the file
      Extractor theirs(std::make_shared<const PreparedGrid>(prepare(own, o)));
      theirs.extract(mid);
      EXPECT_EQ(triangles_of(mine.mesh()), triangles_of(theirs.mesh())) << "source " << si << " mutant " << m << " (" << kinds << ")";
      if (!grid->hierarchy) {  // the hierarchy dropped: --max-error is refused
        EXPECT_THROW(HierarchyQuery{grid}, InputError);
        continue;
      }
      const HierarchyQuery query(grid);
      EXPECT_EQ(query.prepared_error(), prepared_error) << kinds;
      for (double factor : {1.0, 3.0, 20.0}) {
        const double e = std::max(prepared_error, factor * std::max(src.error, 0.005) * (r.max - r.min));
        PrepareOptions o;
        o.max_error = e;
        o.max_displacement = src.displacement;
        o.pad_lattice = false;
        const auto expected = std::make_shared<const PreparedGrid>(prepare(own, o));
        Extractor ex(expected);
        for (double f : {0.25, 0.5, 0.75}) {
          const double iso = r.min + f * (r.max - r.min);
          ex.extract(iso);
          EXPECT_EQ(triangles_of(query.extract(iso, e, 0)), triangles_of(ex.mesh()))
              << "source " << si << " mutant " << m << " (" << kinds << ") error " << e << " iso " << iso;
          ++compared;
        }
      }
    }
  }
  // Not vacuous: the unmutated files and those whose lies are harmless (geometry, the index dropped)
  // loaded, most others did not.
  EXPECT_GE(loaded, 3 + 30) << loaded << " loaded, " << refused << " refused";
  EXPECT_GE(refused, 400) << loaded << " loaded, " << refused << " refused";
  std::cout << "differential: " << loaded << " mutants loaded (" << compared << " surfaces compared), " << refused << " refused\n";
}

// GridParts::hierarchy (the distance query's load): the same vertices and hierarchy as the whole
// file, no tetrahedra or index, the file's tetrahedra still counted, and the same surfaces.
TEST(GridFileHierarchyParts, AreTheWholeLoadsVerticesAndHierarchyAndGiveItsSurfaces) {
  testutil::TempDir t("parts_same");
  save_grid(bisection(bumpy({13, 10, 7}, 3), 0.02), t / "g.adg", true);
  const auto whole = std::make_shared<const PreparedGrid>(load_grid(t / "g.adg"));
  const auto parts = std::make_shared<const PreparedGrid>(load_grid(t / "g.adg", GridParts::hierarchy));
  EXPECT_EQ(parts->grid.ijk, whole->grid.ijk);
  EXPECT_EQ(parts->grid.values, whole->grid.values);
  EXPECT_EQ(parts->grid.gradients, whole->grid.gradients);
  EXPECT_EQ(parts->grid.source.dims, whole->grid.source.dims);
  ASSERT_TRUE(parts->hierarchy);
  EXPECT_EQ(parts->hierarchy->error_code, whole->hierarchy->error_code);
  EXPECT_EQ(parts->hierarchy->value_span, whole->hierarchy->value_span);
  EXPECT_EQ(parts->grid.tet_count(), 0u);
  EXPECT_TRUE(parts->index.nodes.empty());
  EXPECT_EQ(parts->stats.tetrahedra, whole->grid.tet_count());
  EXPECT_THROW(Extractor{parts}, std::invalid_argument);  // its surfaces would be empty
  const HierarchyQuery a(whole), b(parts);
  EXPECT_EQ(a.extract(0.5, a.prepared_error() * 4, 0).triangles, b.extract(0.5, b.prepared_error() * 4, 0).triangles);
  for (double iso : {0.3, 0.9})
    for (double d : {0.0, 0.5, 2.0}) {
      const Mesh ma = a.extract_within(iso, d), mb = b.extract_within(iso, d);
      EXPECT_GT(ma.triangle_count(), 0u);
      EXPECT_EQ(ma.triangles, mb.triangles) << iso << " " << d;
      EXPECT_EQ(ma.positions, mb.positions) << iso << " " << d;
    }
}

// Issue 38: a load shared over processes (load_grid_shared, the hierarchy's checks cut among them)
// gives every process the grid one process loads, whole or in part, bisection grid or Delaunay;
// processes that read different files all refuse, naming the first that differs.
TEST(GridFileSharedLoad, GivesEveryProcessTheGridOneProcessLoads) {
  testutil::TempDir t("shared_load");
  const PreparedGrid b = bisection(bumpy({19, 12, 9}, 4), 0.02, 0.5);
  save_grid(b, t / "b.adg");
  save_grid(b, t / "bi.adg", true);  // with its index: more sections read for the checksum alone
  save_grid(delaunay(make_synthetic("sphere", 11, ScalarType::f32), 0.05), t / "d.adg");
  for (const std::string name : {"b.adg", "bi.adg", "d.adg"})
    for (GridParts parts : {GridParts::all, GridParts::hierarchy_or_all})
      for (int processes : {1, 2, 3, 4}) {
        const std::string path = t / name;
        const PreparedGrid one = load_grid(path, parts);
        const SharedLoad shared = load_shared(std::vector<std::string>(static_cast<std::size_t>(processes), path), parts);
        for (int p = 0; p < processes; ++p) {
          SCOPED_TRACE(fmt::format("{}, parts {}, process {} of {}", name, static_cast<int>(parts), p, processes));
          ASSERT_EQ(shared.refusals[static_cast<std::size_t>(p)], "");
          const PreparedGrid& g = *shared.grids[static_cast<std::size_t>(p)];
          EXPECT_EQ(g.grid.ijk, one.grid.ijk);
          EXPECT_EQ(g.grid.values, one.grid.values);
          EXPECT_EQ(g.grid.tets, one.grid.tets);
          EXPECT_EQ(g.stats.tetrahedra, one.stats.tetrahedra);
          ASSERT_EQ(g.hierarchy.has_value(), one.hierarchy.has_value());
          if (one.hierarchy) {
            EXPECT_EQ(g.hierarchy->error_code, one.hierarchy->error_code);
            EXPECT_EQ(g.hierarchy->displacement_code, one.hierarchy->displacement_code);
            EXPECT_EQ(g.hierarchy->value_span, one.hierarchy->value_span);
          }
        }
      }
  // Another file on process 1 of 3 (another header, or only other contents): every process
  // refuses it with the same words, whatever it would read of it.
  for (const std::string other : {"d.adg", "bi.adg"})
    for (GridParts parts : {GridParts::all, GridParts::hierarchy_or_all}) {
      const SharedLoad mixed = load_shared({t / "b.adg", t / other, t / "b.adg"}, parts);
      for (std::size_t p = 0; p < 3; ++p)
        EXPECT_NE(mixed.refusals[p].find("process 1 read other bytes than process 0"), std::string::npos) << other << " " << p;
      EXPECT_NE(mixed.refusals[0].find(t / "b.adg"), std::string::npos);
    }
  // The same file, other parts on process 1 (with its index, so that the parts read differ):
  // every process refuses, none waits for a message the others do not send.
  {
    testutil::Hub hub;
    std::vector<std::string> said(2);
    testutil::as_processes(hub, 2, [&](ShareTransport& tr, int p) {
      try {
        load_grid_shared(t / "bi.adg", p == 0 ? GridParts::all : GridParts::tetrahedra, tr);
      } catch (const std::exception& e) {
        said[static_cast<std::size_t>(p)] = e.what();
      }
    });
    EXPECT_EQ(hub.left(), 0u);
    for (const auto& m : said) EXPECT_NE(m.find("process 1 read other bytes than process 0"), std::string::npos) << m;
  }
  // The same header, other contents on process 2 (each file's checksum matches its bytes): a
  // value, read whole by every process, or the first or the last tetrahedron, read a piece per
  // process for the checksum alone with the hierarchy's parts (their checksums then combine
  // pieces of each other's files: they must not refuse one by one, leaving the others waiting).
  // Every process refuses, in the same words.
  for (int lie = 0; lie < 3; ++lie) {
    PreparedGrid changed = b;
    if (lie == 0) changed.grid.values[7] = std::nextafter(changed.grid.values[7], 1e30);
    if (lie == 1) std::swap(changed.grid.tets.front()[1], changed.grid.tets.front()[2]);
    if (lie == 2) std::swap(changed.grid.tets.back()[1], changed.grid.tets.back()[2]);
    save_grid(changed, t / "c.adg");
    for (GridParts parts : {GridParts::all, GridParts::hierarchy_or_all}) {
      const SharedLoad mixed = load_shared({t / "b.adg", t / "b.adg", t / "c.adg"}, parts);
      for (std::size_t p = 0; p < 3; ++p)
        EXPECT_NE(mixed.refusals[p].find("process 2 read other bytes than process 0"), std::string::npos)
            << "lie " << lie << ", process " << p << ": " << mixed.refusals[p];
    }
  }
}

// A process of a shared load that cannot open its file, or not as a grid file, made the others
// wait for it (regression: Python's adaptiso.load(comm=) hung on every other rank). Now every
// process refuses with its message, word for word, naming it; through load_grid_shared and through
// an OpenGridFile opened and loaded with the transport (Python's lazy route).
TEST(GridFileSharedLoad, AProcessThatCannotReadItsFileMakesEveryProcessRefuseNamingIt) {
  testutil::TempDir t("shared_unreadable");
  save_grid(bisection(bumpy({13, 9, 7}, 4), 0.02, 0.5), t / "b.adg");
  testutil::write_bytes(t / "short.adg", std::string(10, 'x'));
  std::string noise(4096, '\0');
  for (std::size_t i = 0; i < noise.size(); ++i) noise[i] = static_cast<char>(i * 37 + 11);
  testutil::write_bytes(t / "noise.adg", noise);
  std::filesystem::create_directory(t / "folder.adg");
  const std::pair<std::string, std::string> bad[] = {
      {"absent.adg", "no such file"}, {"short.adg", "too short"}, {"noise.adg", "bad magic"}, {"folder.adg", "folder"}};
  for (const auto& [name, fragment] : bad)
    for (int q = 0; q < 3; ++q)
      for (bool held_open : {false, true}) {
        SCOPED_TRACE(fmt::format("{} on process {}, {}", name, q, held_open ? "OpenGridFile" : "load_grid_shared"));
        std::vector<std::string> paths(3, t / "b.adg");
        paths[static_cast<std::size_t>(q)] = t / name;
        const SharedLoad shared = load_shared(paths, GridParts::hierarchy_or_all, held_open);
        for (int p = 0; p < 3; ++p) EXPECT_EQ(shared.refusals[static_cast<std::size_t>(p)], shared.refusals[0]) << p;
        const std::string& m = shared.refusals[0];
        EXPECT_NE(m.find(t / name), std::string::npos) << m;
        EXPECT_NE(m.find(fragment), std::string::npos) << m;
        if (q > 0) EXPECT_NE(m.find(fmt::format("(process {})", q)), std::string::npos) << m;
      }
}

TEST(GridFileHierarchyParts, OfAGridWithoutAHierarchyAreRefused) {
  testutil::TempDir t("parts_delaunay");
  save_grid(delaunay(make_synthetic("sphere", 11, ScalarType::f32), 0.05), t / "d.adg", true);
  try {
    load_grid(t / "d.adg", GridParts::hierarchy);
    FAIL() << "loaded";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find(t / "d.adg"), std::string::npos) << m;
    EXPECT_NE(m.find("no bisection hierarchy"), std::string::npos) << m;
  }
}

// The tetrahedra and the index are skipped, not trusted: damage in them still fails the checksum,
// a count that disagrees with the hierarchy's leaves is refused, and a lie in their contents alone
// (refused by the whole load) changes nothing the hierarchy's load gives.
TEST(GridFileHierarchyParts, ChecksumTheSkippedSectionsAndCountTheLeaves) {
  testutil::TempDir t("parts_lies");
  save_grid(bisection(bumpy({13, 10, 7}, 4), 0.02), t / "g.adg", true);
  const GridSections honest = sections_of(t / "g.adg");
  auto refused = [&](const std::string& path) {
    try {
      load_grid(path, GridParts::hierarchy);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  // A bit flipped in the tetrahedra, then in the index, the checksum left as it was.
  std::string bytes = testutil::read_bytes(t / "g.adg");
  const std::size_t tets_at = 64 + honest.meta.size() + honest.ijk.size() + honest.values.size() + honest.gradients.size();
  for (std::size_t at : {tets_at + 5, tets_at + honest.tets.size() + honest.nodes.size() + 3}) {
    std::string flipped = bytes;
    flipped[at] = static_cast<char>(flipped[at] ^ 0x10);
    testutil::write_bytes(t / "flipped.adg", flipped);
    EXPECT_NE(refused(t / "flipped.adg").find("checksum"), std::string::npos) << at;
  }
  // One tetrahedron fewer, and one index entry (a fresh checksum): the count disagrees with the
  // hierarchy's leaves.
  GridSections fewer = honest;
  fewer.tets.resize(fewer.tets.size() - 16);
  fewer.by_min.resize(fewer.by_min.size() - 4);
  fewer.by_max.resize(fewer.by_max.size() - 4);
  save_sections(fewer, t / "fewer.adg");
  EXPECT_NE(refused(t / "fewer.adg").find("leaves"), std::string::npos) << refused(t / "fewer.adg");
  // Two tetrahedra swapped (a fresh checksum): the whole load refuses, the hierarchy's is unchanged.
  GridSections swapped = honest;
  std::swap_ranges(swapped.tets.begin(), swapped.tets.begin() + 16, swapped.tets.begin() + 16);
  save_sections(swapped, t / "swapped.adg");
  expect_refused(t / "swapped.adg", "not the hierarchy's leaves");
  ASSERT_EQ(refused(t / "swapped.adg"), "");
  const auto a = std::make_shared<const PreparedGrid>(load_grid(t / "g.adg", GridParts::hierarchy));
  const auto b = std::make_shared<const PreparedGrid>(load_grid(t / "swapped.adg", GridParts::hierarchy));
  EXPECT_EQ(HierarchyQuery(a).extract_within(0.5, 1.0).triangles, HierarchyQuery(b).extract_within(0.5, 1.0).triangles);
}

// Up to version 4 the checksum restarted after every empty array; the skipped index of a constant
// volume (no entries) must restart it as reading it would.
TEST(GridFileHierarchyParts, ReadOlderChecksumsThatRestartAtEmptyArrays) {
  testutil::TempDir t("parts_v4");
  Volume v = make_volume({9, 8, 7}, ScalarType::f32);
  for (std::size_t i = 0; i < 9 * 8 * 7; ++i) v.set(i, 3.0);
  save_grid(bisection(v, 0.05), t / "g.adg", true);
  GridSections s = sections_of(t / "g.adg");
  ASSERT_TRUE(s.by_min.empty());
  ASSERT_EQ(s.flags & GridSections::kHasHierarchy, GridSections::kHasHierarchy);
  s.version = 4;
  save_sections(s, t / "v4.adg");
  EXPECT_NO_THROW(load_grid(t / "v4.adg"));
  EXPECT_NO_THROW(load_grid(t / "v4.adg", GridParts::hierarchy));
}

// OpenGridFile: what a later load reads is the file as opened, renamed over or deleted since; its
// messages name the path given, not the descriptor; a FIFO is refused without waiting for a writer;
// hierarchy_or_all loads a Delaunay grid whole.
TEST(OpenGridFile, ReadsTheFileAsOpenedAndNamesItsPath) {
  testutil::TempDir t("open_grid");
  const PreparedGrid first = bisection(bumpy({13, 10, 7}, 3), 0.02);
  save_grid(first, t / "g.adg");
  const OpenGridFile file(t / "g.adg");
  const PreparedGrid part = file.load(GridParts::hierarchy_or_all);
  EXPECT_TRUE(loaded_in_part(part));
  EXPECT_EQ(part.stats.tetrahedra, first.grid.tet_count());
  save_grid(bisection(bumpy({13, 10, 7}, 5), 0.02), t / "other.adg");
  std::filesystem::rename(t / "other.adg", t / "g.adg");
  const PreparedGrid whole = file.load(GridParts::all);
  EXPECT_FALSE(loaded_in_part(whole));
  EXPECT_EQ(whole.grid.tets, first.grid.tets);
  EXPECT_EQ(whole.grid.values, first.grid.values);
  std::filesystem::remove(t / "g.adg");
  EXPECT_EQ(file.load(GridParts::all).grid.tets, first.grid.tets);

  save_grid(first, t / "h.adg");
  GridSections swapped = sections_of(t / "h.adg");
  std::swap_ranges(swapped.tets.begin(), swapped.tets.begin() + 16, swapped.tets.begin() + 16);
  save_sections(swapped, t / "lie.adg");
  const OpenGridFile lie(t / "lie.adg");
  EXPECT_TRUE(loaded_in_part(lie.load(GridParts::hierarchy_or_all)));
  try {
    lie.load(GridParts::all);
    FAIL() << "loaded";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_EQ(m.rfind(t / "lie.adg", 0), 0u) << m;
    EXPECT_NE(m.find("not the hierarchy's leaves"), std::string::npos) << m;
  }

  // Rewritten in place after the load in part (the same file, other bytes): the whole load checks
  // everything again rather than trusting the first walk, and finds the lie in the value spans.
  {
    save_grid(first, t / "inplace.adg");
    const OpenGridFile inplace(t / "inplace.adg");
    EXPECT_TRUE(loaded_in_part(inplace.load(GridParts::hierarchy_or_all)));
    GridSections spans = sections_of(t / "inplace.adg");
    spans.spans[0] = static_cast<char>(spans.spans[0] ^ 0x40);
    save_sections(spans, t / "spans.adg");
    const std::string lie_bytes = testutil::read_bytes(t / "spans.adg");
    ASSERT_EQ(lie_bytes.size(), std::filesystem::file_size(t / "inplace.adg"));
    std::fstream same(t / "inplace.adg", std::ios::in | std::ios::out | std::ios::binary);
    same.write(lie_bytes.data(), static_cast<std::streamsize>(lie_bytes.size()));
    same.close();
    try {
      inplace.load(GridParts::all);
      FAIL() << "trusted the first walk";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("value span"), std::string::npos) << e.what();
    }
  }

  ASSERT_EQ(mkfifo((t / "fifo.adg").c_str(), 0600), 0);
  try {
    const OpenGridFile fifo(t / "fifo.adg");
    fifo.load(GridParts::hierarchy_or_all);
    FAIL() << "loaded a FIFO";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()).rfind(t / "fifo.adg", 0), 0u) << e.what();
  }
  try {
    const OpenGridFile missing(t / "missing.adg");
    FAIL() << "opened a missing file";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(t / "missing.adg"), std::string::npos) << e.what();
  }

  save_grid(delaunay(make_synthetic("sphere", 11, ScalarType::f32), 0.05), t / "d.adg");
  const PreparedGrid d = OpenGridFile(t / "d.adg").load(GridParts::hierarchy_or_all);
  EXPECT_FALSE(loaded_in_part(d));
  EXPECT_GT(d.grid.tet_count(), 0u);
}
