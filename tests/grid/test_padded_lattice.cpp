// The padded lattice (bisection.hpp; prepare.hpp: pad_lattice) against references: the padding
// rule, the padded volume voxel by voxel, a grid's cost against the next size up (issue 37's box
// lining), the clipped surface at the finest level against the unpadded grid's triangle for
// triangle, every extraction route's surface inside the volume's box with its boundary on the
// box's faces, the bricks read through a padded source against the padded volume, the grid file.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <map>
#include <nlohmann/json.hpp>
#include <random>

#include "adaptiso/bisection.hpp"
#include "adaptiso/bisection_bricks.hpp"
#include "adaptiso/brick_shares.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/grid_file.hpp"
#include "adaptiso/hierarchy_query.hpp"
#include "adaptiso/marching_tetrahedra.hpp"
#include "adaptiso/point_cloud.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/volume_regions.hpp"
#include "test_util.hpp"

using namespace adaptiso;

// Helpers and tests in a namespace of their own: the test sources are compiled in unity batches.
namespace padded_lattice_test {

// A quadratic bowl centred near the far corner: its iso-surfaces (spheres) cross all three far
// faces, and no diamond anywhere has zero error (every midpoint lies off the chord), so error 0
// refines every grid to its unit tetrahedra.
Volume bowl(const Dims& d, const Vec3& spacing, ScalarType type = ScalarType::f32, double scale = 1) {
  Volume v = make_volume(d, type);
  v.spacing = spacing;
  const double c[3] = {0.8 * double(d[0] - 1), 0.75 * double(d[1] - 1), 0.85 * double(d[2] - 1)};
  for (std::int64_t z = 0; z < d[2]; ++z)
    for (std::int64_t y = 0; y < d[1]; ++y)
      for (std::int64_t x = 0; x < d[0]; ++x) {
        const double r2 = (x - c[0]) * (x - c[0]) + (y - c[1]) * (y - c[1]) + (z - c[2]) * (z - c[2]);
        v.set(v.index(x, y, z), scale * r2);
      }
  return v;
}

std::shared_ptr<const PreparedGrid> prepared(const Volume& v, double max_error, bool pad) {
  PrepareOptions o;
  o.max_error = max_error;
  o.pad_lattice = pad;
  return std::make_shared<const PreparedGrid>(prepare(v, o));
}

using Corner = std::array<float, 3>;
using Triangle = std::array<Corner, 6>;  // corners, then their normals

std::vector<Triangle> triangles_of(const Mesh& m) { return testutil::sorted_triangles<true>(m); }  // with normals

// A surface's census in index coordinates: vertices past the volume's box, edges used by more
// than two triangles or twice in one direction, and boundary edges that do not lie on one face
// of the box (both ends within `slack` of the same face plane).
struct Census {
  std::size_t outside = 0, nonmanifold = 0, misoriented = 0, off_box = 0, boundary = 0, on_far_faces = 0;
};
Census census(const Mesh& m, const Volume& v) {
  const double slack = 1e-4;
  std::vector<Vec3> u(m.vertex_count());
  Census c;
  auto on_face = [&](const Vec3& p, int a, double f) { return std::abs(p[a] - f) <= slack; };
  for (std::size_t i = 0; i < u.size(); ++i) {
    const auto& p = m.positions[i];
    u[i] = v.world_to_voxel({p[0], p[1], p[2]});
    bool far = false;
    for (int a = 0; a < 3; ++a) {
      c.outside += u[i][a] < -slack || u[i][a] > double(v.dims[a] - 1) + slack;
      far |= on_face(u[i], a, double(v.dims[a] - 1));
    }
    c.on_far_faces += far;
  }
  std::map<std::pair<std::uint32_t, std::uint32_t>, std::pair<int, int>> edges;
  for (const auto& t : m.triangles)
    for (int e = 0; e < 3; ++e) {
      const std::uint32_t a = t[e], b = t[(e + 1) % 3];
      auto& n = edges[{std::min(a, b), std::max(a, b)}];
      (a < b ? n.first : n.second)++;
    }
  for (const auto& [k, n] : edges) {
    if (n.first + n.second > 2) ++c.nonmanifold;
    if (n.first > 1 || n.second > 1) ++c.misoriented;
    if (n.first + n.second != 1) continue;
    ++c.boundary;
    bool on = false;
    for (int a = 0; a < 3; ++a)
      for (double f : {0.0, double(v.dims[a] - 1)}) on |= on_face(u[k.first], a, f) && on_face(u[k.second], a, f);
    c.off_box += !on;
  }
  return c;
}

void expect_ends_on_the_box(const Mesh& m, const Volume& v, const std::string& route) {
  SCOPED_TRACE(route);
  const Census c = census(m, v);
  EXPECT_GT(m.triangle_count(), 0u);
  EXPECT_EQ(c.outside, 0u);
  EXPECT_EQ(c.nonmanifold, 0u);
  EXPECT_EQ(c.misoriented, 0u);
  EXPECT_EQ(c.off_box, 0u);
  EXPECT_GT(c.on_far_faces, 0u);  // the surface does reach the far faces: the clip was exercised
}

TEST(PaddedLattice, FarFacesMoveOutToMultiplesOfASmallStepAndTheRootCubeNeverGrows) {
  EXPECT_EQ(bisection_lattice_dims({64, 512, 361}), (Dims{65, 513, 361}));
  EXPECT_EQ(bisection_lattice_dims({133, 10, 20}), (Dims{137, 11, 21}));
  EXPECT_EQ(bisection_lattice_dims({2, 5, 1}), (Dims{2, 5, 1}));
  for (std::int64_t n = 2; n <= 2100; ++n) {
    const std::int64_t p = bisection_lattice_dims({n, 2, 2})[0];
    EXPECT_GE(p, n);
    EXPECT_LE(p - n, std::min<std::int64_t>(7, (n - 1) / 4)) << n;
    EXPECT_EQ(std::bit_ceil(std::uint64_t(p - 1)), std::bit_ceil(std::uint64_t(n - 1))) << n;
  }
}

TEST(PaddedLattice, PaddedVolumeReflectsTheLastSlicesAndKeepsTheGeometry) {
  Volume v = testutil::pattern_volume({5, 4, 3}, ScalarType::i16);
  v.spacing = {0.5, 1, 2};
  v.origin = {1, 2, 3};
  const ValueRange range = value_range(v);
  const Volume p = pad_volume(v, {8, 4, 6}, range);
  ASSERT_EQ(p.dims, (Dims{8, 4, 6}));
  EXPECT_EQ(p.type, v.type);
  EXPECT_EQ(p.spacing, v.spacing);
  EXPECT_EQ(p.origin, v.origin);
  // Odd reflection about the last voxel, x then z (4 slices past a volume of 3: the last one
  // mirrors past the first slice and takes the first), within the value range at each step.
  auto along_x = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    return x < 5 ? v.at(x, y, z) : std::clamp(2 * v.at(4, y, z) - v.at(std::max<std::int64_t>(8 - x, 0), y, z), range.min, range.max);
  };
  for (std::int64_t z = 0; z < 6; ++z)
    for (std::int64_t y = 0; y < 4; ++y)
      for (std::int64_t x = 0; x < 8; ++x) {
        const double expected = z < 3 ? along_x(x, y, z) : 2 * along_x(x, y, 2) - along_x(x, y, std::max<std::int64_t>(4 - z, 0));
        EXPECT_EQ(p.at(x, y, z), std::clamp(expected, range.min, range.max)) << x << " " << y << " " << z;
      }
  // Within the range given (a grid's values stay within its source's).
  Volume ramp = make_volume({4, 1, 1}, ScalarType::u8);
  ramp.set(0, 0), ramp.set(1, 200), ramp.set(2, 250), ramp.set(3, 230);
  const Volume r = pad_volume(ramp, {7, 1, 1}, {0, 250});
  EXPECT_EQ(r.at(4, 0, 0), 210);  // 2·230 − 250
  EXPECT_EQ(r.at(5, 0, 0), 250);  // 2·230 − 200 = 260, clamped
  EXPECT_EQ(r.at(6, 0, 0), 250);  // 2·230 − 0
  ramp.set(3, 10);
  EXPECT_EQ(pad_volume(ramp, {5, 1, 1}, {0, 250}).at(4, 0, 0), 0);  // 2·10 − 250 < 0
  EXPECT_THROW(pad_volume(v, {4, 4, 3}, range), std::invalid_argument);
}

// Issue 37, the box lining: a 64³ volume's far faces lie at the odd index 63, where only unit
// tetrahedra fit; on the padded lattice it costs what the 65³ volume it was cropped from costs.
TEST(PaddedLattice, A64CubedCropCostsAtMostOneAndAHalfTimesIts65CubedVolume) {
  const Dims big{65, 65, 65};
  Volume whole = make_volume(big, ScalarType::f32), crop = make_volume({64, 64, 64}, ScalarType::f32);
  for (std::int64_t z = 0; z < 65; ++z)
    for (std::int64_t y = 0; y < 65; ++y)
      for (std::int64_t x = 0; x < 65; ++x) {
        const double r2 = (x - 20.0) * (x - 20.0) + (y - 30.0) * (y - 30.0) + (z - 40.0) * (z - 40.0);
        const double f = 1000 * std::exp(-r2 / (2 * 18.0 * 18.0)) + 2 * x;
        whole.set(whole.index(x, y, z), f);
        if (x < 64 && y < 64 && z < 64) crop.set(crop.index(x, y, z), f);
      }
  const double bound = 10;  // data units, of a range of about 1,100
  const double cost65 = double(prepared(whole, bound, true)->grid.tet_count());
  const double cost64 = double(prepared(crop, bound, true)->grid.tet_count());
  const double lined64 = double(prepared(crop, bound, false)->grid.tet_count());
  EXPECT_LE(cost64, 1.5 * cost65);
  EXPECT_GT(lined64, 3 * cost65);  // what the padding removes (7.6× measured on a CT crop)
}

// At error 0 both grids are the unit tetrahedra of the volume's voxels, except next to the far
// faces: the reflection makes an edge across a face linear (its ends average to the face's
// voxel), so the padded grid keeps the pair of unit cubes around it whole there. Two voxels in
// from the far faces the clipped surface is the unpadded grid's, triangle for triangle, normals
// too; the rest of it ends on the box.
TEST(PaddedLattice, ClippedSurfaceAtErrorZeroIsTheUnpaddedGridsAwayFromTheFarFaces) {
  for (const Dims d : {Dims{20, 14, 10}, Dims{34, 18, 11}, Dims{12, 39, 6}}) {
    SCOPED_TRACE(::testing::Message() << d[0] << "x" << d[1] << "x" << d[2]);
    const Volume v = bowl(d, {0.7, 1.0, 1.9});
    ASSERT_NE(bisection_lattice_dims(d), d);
    const auto padded = prepared(v, 0, true), plain = prepared(v, 0, false);
    ASSERT_TRUE(padded->grid.source.padded());
    EXPECT_EQ(padded->grid.source.volume_box(), d);
    EXPECT_FALSE(plain->grid.source.padded());
    // Corners in grid-frame coordinates (axis-aligned, origin 0): at least 2 voxels inside.
    auto inner = [&](const Mesh& m) {
      std::vector<Triangle> out;
      for (const Triangle& t : triangles_of(m)) {
        bool in = true;
        for (int i = 0; i < 3; ++i)
          for (int a = 0; a < 3; ++a) in &= t[i][a] <= float(v.spacing[a] * double(d[a] - 3));
        if (in) out.push_back(t);
      }
      return out;
    };
    Extractor a(padded), b(plain);
    for (double r : {2.5, 4.5, 6.5}) {
      a.extract(r * r);
      b.extract(r * r);
      const auto kept = inner(b.mesh());
      ASSERT_GT(kept.size(), 0u);
      EXPECT_EQ(inner(a.mesh()), kept) << "iso " << r * r;
      expect_ends_on_the_box(a.mesh(), v, "Extractor");
    }
  }
}

// Every route's surface of a coarser grid: inside the volume's box, manifold and oriented, its
// boundary on the box's faces; on an oblique frame too (the clip goes through the frame's inverse).
TEST(PaddedLattice, EveryExtractionRouteEndsItsSurfaceOnTheVolumesBox) {
  for (bool oblique : {false, true}) {
    SCOPED_TRACE(oblique ? "oblique" : "axis-aligned");
    Volume v = bowl({34, 18, 11}, {0.7, 1.0, 1.9}, ScalarType::f32, 0.05);  // shallow: tetrahedra 8 voxels across at the faces
    if (oblique) {
      const double c = std::cos(0.3), s = std::sin(0.3);
      v.direction = {c, -s, 0, s, c, 0, 0, 0, 1};
      v.origin = {-40, 12.5, 300};
    }
    const auto g = prepared(v, 1.5, true);
    ASSERT_TRUE(g->grid.source.padded());
    const double iso = 0.05 * 6.5 * 6.5;
    Extractor ex(g);
    ex.extract(iso - 0.45);
    ex.extract(iso);  // a step from the surface before
    expect_ends_on_the_box(ex.mesh(), v, "Extractor, stepped");
    Extractor fresh(g);
    fresh.extract(iso);
    EXPECT_EQ(triangles_of(ex.mesh()), triangles_of(fresh.mesh()));
    // The march order and the cut edges follow the clipped mesh.
    const auto& order = ex.triangles_in_march_order();
    ASSERT_EQ(order.size(), ex.mesh().triangle_count());
    EXPECT_TRUE(std::is_permutation(order.begin(), order.end(), fresh.triangles_in_march_order().begin()));
    const auto& edges = ex.vertex_edges();
    ASSERT_EQ(edges.size(), ex.mesh().vertex_count());
    const std::size_t clipped = static_cast<std::size_t>(std::count(edges.begin(), edges.end(), kClippedVertex));
    EXPECT_GT(clipped, 0u);
    EXPECT_LT(clipped, edges.size());
    expect_ends_on_the_box(march_tetrahedra(g->grid, fresh.active(), iso), v, "march_tetrahedra");
    const HierarchyQuery q(g);
    expect_ends_on_the_box(q.extract(iso, 3), v, "hierarchy query, max error");
    for (int rounds : {0, 2}) expect_ends_on_the_box(q.extract_within(iso, 1.5, nullptr, rounds), v, "distance query");
  }
}

// The bricks of the padded lattice read through padded_source give the padded volume's hierarchy,
// byte for byte, also where a brick lies wholly in the padding.
TEST(PaddedLattice, BricksReadThroughThePaddedSourceGiveThePaddedVolumesHierarchy) {
  const Volume v = bowl({37, 21, 14}, {1, 1, 1}, ScalarType::i16);
  const Dims lattice = bisection_lattice_dims(v.dims);
  ASSERT_EQ(lattice, (Dims{41, 21, 15}));
  const ValueRange range = value_range(v);
  const Volume padded = pad_volume(v, lattice, range);
  for (bool displacement : {false, true}) {
    const BisectionErrors whole = bisection_errors(padded, range, displacement);
    for (std::int64_t side : {4, 8}) {
      const BisectionErrors bricked =
          bisection_errors_bricked(lattice, range, side, padded_source(region_source(v), v.dims, range), displacement);
      EXPECT_EQ(bricked.code, whole.code) << side;
      EXPECT_EQ(bricked.displacement_code, whole.displacement_code) << side;
    }
  }
}

// A compressed file is read slab by slab: the padded source reads the reflection's slices below
// a slab at the far z face, so the hold announced for the slab must reach them too (it was clamped
// at the face only, and a small brick side then read slices the stream no longer held).
TEST(PaddedLattice, StreamedBricksHoldTheSlicesTheReflectionReads) {
  testutil::TempDir t("padded_stream");
  const Volume v = bowl({13, 11, 34}, {1, 1, 1}, ScalarType::i16);
  testutil::write_bytes(t / "v.nrrd", "NRRD0004\ntype: short\ndimension: 3\nsizes: 13 11 34\nendian: little\nencoding: gzip\n\n" +
                                          testutil::compress(testutil::bytes_of(v), true));
  RegionReader reader(t / "v.nrrd");
  ASSERT_TRUE(reader.streams());
  const Dims lattice = bisection_lattice_dims(v.dims);
  ASSERT_EQ(lattice[2], 41);  // 7 slices past the last (33), which reflect slices 26 to 32
  const ValueRange range = value_range(v);
  const BisectionErrors whole = bisection_errors(pad_volume(v, lattice, range), range);
  for (std::int64_t side : {2, 4}) {
    const ReaderSource read = reader_source(reader, lattice, range);
    const auto bricks = bisection_share_errors(brick_grid(lattice, side), 0, 1, read.source, range, false, read.hold);
    EXPECT_EQ(bisection_combine_bricks(brick_grid(lattice, side), bricks, range).code, whole.code) << side;
  }
}

TEST(PaddedLattice, GridFileKeepsTheVolumesBoxAndItsSurfaces) {
  testutil::TempDir t("padded_lattice");
  const Volume v = bowl({20, 14, 10}, {0.7, 1.0, 1.9});
  const auto g = prepared(v, 1.5, true);
  save_grid(*g, t / "g.adg");
  const auto loaded = std::make_shared<const PreparedGrid>(load_grid(t / "g.adg"));
  EXPECT_EQ(loaded->grid.source.volume_dims, v.dims);
  EXPECT_EQ(loaded->grid.source.dims, bisection_lattice_dims(v.dims));
  Extractor a(g), b(loaded);
  a.extract(20);
  b.extract(20);
  EXPECT_EQ(triangles_of(a.mesh()), triangles_of(b.mesh()));
  // An unpadded grid writes no volume_dims: its file keeps the bytes it had.
  save_grid(*prepared(v, 1.5, false), t / "plain.adg");
  EXPECT_EQ(testutil::read_bytes(t / "plain.adg").find("volume_dims"), std::string::npos);
  EXPECT_NE(testutil::read_bytes(t / "g.adg").find("volume_dims"), std::string::npos);
}

// Noise at error 0: every voxel off the far faces' last slices is a vertex (the odd reflection
// makes some of those slices' voxels the midpoints of straight edges, which need none). The points
// written are the grid's vertices inside the volume's box, each voxel at most once with its value,
// none from the padding; the .vtu flags the padded grid's vertices, an unpadded grid's has no flag.
TEST(PaddedLattice, ExportsTellTheVolumesVoxelsFromTheCopiesPastItsFarFaces) {
  testutil::TempDir t("padded_lattice");
  Volume v = make_volume({13, 10, 7}, ScalarType::f32);
  v.spacing = {0.7, 1.0, 1.9};
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> noise(0, 100);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, noise(rng));
  const auto g = prepared(v, 0, true);
  ASSERT_TRUE(g->grid.source.padded());
  std::size_t past = 0;  // vertices with a coordinate past the volume's far faces
  for (const auto& c : g->grid.ijk) past += c[0] >= 13 || c[1] >= 10 || c[2] >= 7;
  ASSERT_GT(past, 0u);
  const std::size_t count = g->grid.vertex_count() - past;
  write_points_ply(t / "p.ply", g->grid);
  const std::string ply = testutil::read_bytes(t / "p.ply");
  const std::size_t body = ply.find("end_header\n") + 11;
  ASSERT_NE(ply.find(fmt::format("element vertex {}\n", count)), std::string::npos);
  ASSERT_EQ(ply.size() - body, count * 28);  // x y z i j k value
  std::vector<int> seen(std::size_t(v.voxel_count()), 0);
  for (std::size_t r = 0; r < count; ++r) {
    std::int32_t ijk[3];
    float value;
    std::memcpy(ijk, ply.data() + body + 28 * r + 12, 12);
    std::memcpy(&value, ply.data() + body + 28 * r + 24, 4);
    ASSERT_TRUE(ijk[0] >= 0 && ijk[0] < v.dims[0] && ijk[1] >= 0 && ijk[1] < v.dims[1] && ijk[2] >= 0 && ijk[2] < v.dims[2]) << r;
    const std::int64_t voxel = v.index(ijk[0], ijk[1], ijk[2]);
    ASSERT_EQ(++seen[std::size_t(voxel)], 1) << r;
    EXPECT_EQ(value, float(v.at(voxel))) << r;
  }
  for (std::int64_t k = 0; k + 1 < v.dims[2]; ++k)
    for (std::int64_t j = 0; j + 1 < v.dims[1]; ++j)
      for (std::int64_t i = 0; i + 1 < v.dims[0]; ++i) EXPECT_EQ(seen[std::size_t(v.index(i, j, k))], 1) << i << " " << j << " " << k;
  write_vtu(g->grid, t / "g.vtu");
  EXPECT_NE(testutil::read_bytes(t / "g.vtu").find("Name=\"in_volume\""), std::string::npos);
  write_vtu(prepared(v, 0, false)->grid, t / "plain.vtu");
  EXPECT_EQ(testutil::read_bytes(t / "plain.vtu").find("in_volume"), std::string::npos);
}

// prepare's kept count (--json, the file's metadata, "kept N of M voxels") is of the volume's
// voxels: it counted a padded lattice's copies too (14^3 noise at error 0: 3,311 kept of 2,744
// voxels). A file written with that count is counted again from its vertices when loaded.
TEST(PaddedLattice, KeptCountsTheVolumesVoxelsNotTheCopiesPastItsFarFaces) {
  testutil::TempDir t("padded_lattice");
  Volume v = make_volume({14, 14, 14}, ScalarType::f32);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> noise(0, 100);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, noise(rng));
  const auto g = prepared(v, 0, true);
  ASSERT_TRUE(g->grid.source.padded());
  std::uint64_t inside = 0;
  for (const auto& c : g->grid.ijk) inside += c[0] < 14 && c[1] < 14 && c[2] < 14;
  ASSERT_LT(inside, g->grid.vertex_count());
  EXPECT_EQ(g->stats.kept, inside);
  EXPECT_LE(g->stats.kept, std::uint64_t(v.voxel_count()));
  EXPECT_EQ(g->stats.vertices, g->grid.vertex_count());
  const auto j = nlohmann::json::parse(to_json(g->stats));
  EXPECT_EQ(j["kept"].get<std::uint64_t>(), inside);
  EXPECT_DOUBLE_EQ(j["ratio"].get<double>(), double(inside) / double(v.voxel_count()));
  EXPECT_EQ(j["vertices"].get<std::uint64_t>(), g->grid.vertex_count());
  PreparedGrid old = *g;
  old.stats.kept = old.grid.vertex_count();  // what an older prepare wrote
  old.stats.vertices = 0;
  save_grid(old, t / "old.adg");
  for (const auto parts : {GridParts::all, GridParts::hierarchy}) {
    const PreparedGrid loaded = load_grid(t / "old.adg", parts);
    EXPECT_EQ(loaded.stats.kept, inside);
    EXPECT_EQ(loaded.stats.vertices, g->grid.vertex_count());
  }
  // An unpadded grid keeps every vertex in the box.
  const auto plain = prepared(v, 0, false);
  EXPECT_EQ(plain->stats.kept, plain->grid.vertex_count());
  EXPECT_EQ(plain->stats.vertices, plain->grid.vertex_count());
}

}  // namespace padded_lattice_test
