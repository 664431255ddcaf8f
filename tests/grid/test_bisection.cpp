// The bisection grid against independent references: every voxel checked by brute-force point
// location and linear interpolation in exact integer arithmetic; conformity (faces paired with
// opposite orientation, volumes summing exactly to the box, no hanging vertex); the diamond
// dependencies against the hierarchy built tetrahedron by tetrahedron; the error codes; the
// extracted surface's topology; the same grid for any thread count.
#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include <map>
#include <random>
#include <set>

#include "adaptiso/bisection.hpp"
#include "adaptiso/extractor.hpp"
#include "adaptiso/gradients.hpp"
#include "adaptiso/reduce.hpp"
#include "adaptiso/synthetic.hpp"
#include "adaptiso/volume_io.hpp"
#include "data_sets.hpp"
#include "grid/diamond.hpp"
#include "grid/traversal.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

using I3 = std::array<std::int64_t, 3>;

I3 at(const TetGrid& g, std::uint32_t v) { return {g.ijk[v][0], g.ijk[v][1], g.ijk[v][2]}; }

std::int64_t det(const I3& a, const I3& b, const I3& c, const I3& d) {
  const I3 u{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v{c[0] - a[0], c[1] - a[1], c[2] - a[2]}, w{d[0] - a[0], d[1] - a[1], d[2] - a[2]};
  return u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) + u[2] * (v[0] * w[1] - v[1] * w[0]);
}

struct Check {
  double max_error = 0;
  std::int64_t uncovered = 0;  // voxels in no tetrahedron
};

// Every voxel against every tetrahedron holding it (closed tetrahedra, exact barycentric
// coordinates in index space): the largest |value − linear interpolation|, and voxels no
// tetrahedron holds.
Check brute_force(const Volume& v, const TetGrid& g) {
  Check c;
  std::vector<std::uint8_t> covered(static_cast<std::size_t>(v.voxel_count()), 0);
  for (const auto& t : g.tets) {
    const I3 P[4] = {at(g, t[0]), at(g, t[1]), at(g, t[2]), at(g, t[3])};
    const std::int64_t D = det(P[0], P[1], P[2], P[3]);
    I3 lo = P[0], hi = P[0];
    for (const auto& p : P)
      for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
    for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
      for (std::int64_t y = lo[1]; y <= hi[1]; ++y)
        for (std::int64_t x = lo[0]; x <= hi[0]; ++x) {
          const I3 q{x, y, z};
          const std::int64_t l[4] = {det(q, P[1], P[2], P[3]), det(P[0], q, P[2], P[3]), det(P[0], P[1], q, P[3]),
                                     det(P[0], P[1], P[2], q)};
          if (l[0] < 0 || l[1] < 0 || l[2] < 0 || l[3] < 0) continue;
          double rec = 0;
          for (int i = 0; i < 4; ++i) rec += static_cast<double>(l[i]) / static_cast<double>(D) * g.values[t[i]];
          const std::int64_t idx = v.index(x, y, z);
          covered[static_cast<std::size_t>(idx)] = 1;
          c.max_error = std::max(c.max_error, std::abs(v.at(idx) - rec));
        }
  }
  c.uncovered = static_cast<std::int64_t>(std::count(covered.begin(), covered.end(), 0));
  return c;
}

struct Conformity {
  std::size_t unpaired_interior = 0, same_orientation = 0, shared_by_more = 0, nonpositive = 0, hanging = 0, unused_vertices = 0;
  bool volume_is_box = false;
};

// Faces as sorted vertex triples: each interior face in exactly two tetrahedra, seen in opposite
// orientations; faces used once lie on the box; 6·volumes sum to 6·box exactly; no grid vertex
// strictly inside an edge of a tetrahedron (a hanging vertex).
Conformity conformity(const Volume& v, const TetGrid& g) {
  Conformity c;
  std::map<std::array<std::uint32_t, 3>, std::vector<int>> faces;  // sorted face → orientation parities
  std::int64_t six_volume = 0;
  for (const auto& t : g.tets) {
    const std::int64_t d = det(at(g, t[0]), at(g, t[1]), at(g, t[2]), at(g, t[3]));
    if (d <= 0) ++c.nonpositive;
    six_volume += d;
    // Outward faces of a positive tetrahedron (a,b,c,d): (b,c,d), (a,d,c), (a,b,d), (a,c,b).
    const std::array<std::array<std::uint32_t, 3>, 4> fs = {
        {{t[1], t[2], t[3]}, {t[0], t[3], t[2]}, {t[0], t[1], t[3]}, {t[0], t[2], t[1]}}};
    for (auto f : fs) {
      // Parity of the permutation sorting f: equal parity = same orientation.
      int parity = 0;
      for (int i = 0; i < 3; ++i)
        for (int j = i + 1; j < 3; ++j) parity ^= f[i] > f[j];
      std::sort(f.begin(), f.end());
      faces[f].push_back(parity);
    }
  }
  for (const auto& [f, uses] : faces) {
    if (uses.size() > 2) ++c.shared_by_more;
    if (uses.size() == 2 && uses[0] == uses[1]) ++c.same_orientation;
    if (uses.size() == 1) {
      bool on_box = false;
      for (int a = 0; a < 3; ++a)
        for (std::int64_t side : {std::int64_t{0}, v.dims[a] - 1})
          on_box |= at(g, f[0])[a] == side && at(g, f[1])[a] == side && at(g, f[2])[a] == side;
      if (!on_box) ++c.unpaired_interior;
    }
  }
  c.volume_is_box = six_volume == 6 * (v.dims[0] - 1) * (v.dims[1] - 1) * (v.dims[2] - 1);
  // The selection finds its vertices from the split diamonds, not from the leaves: each must be a
  // leaf's corner.
  std::vector<bool> used(g.vertex_count(), false);
  for (const auto& t : g.tets)
    for (std::uint32_t i : t) used[i] = true;
  c.unused_vertices = static_cast<std::size_t>(std::count(used.begin(), used.end(), false));
  if (g.vertex_count() <= 4000) {
    std::set<I3> vertices;
    for (std::uint32_t i = 0; i < g.vertex_count(); ++i) vertices.insert(at(g, i));
    std::set<std::pair<std::uint32_t, std::uint32_t>> edges;
    for (const auto& t : g.tets)
      for (int a = 0; a < 4; ++a)
        for (int b = a + 1; b < 4; ++b) edges.insert({std::min(t[a], t[b]), std::max(t[a], t[b])});
    for (const auto& [a, b] : edges) {
      const I3 p = at(g, a), q = at(g, b);
      const std::int64_t n = std::gcd(std::gcd(std::abs(q[0] - p[0]), std::abs(q[1] - p[1])), std::abs(q[2] - p[2]));
      for (std::int64_t s = 1; s < n; ++s)
        if (vertices.count({p[0] + (q[0] - p[0]) / n * s, p[1] + (q[1] - p[1]) / n * s, p[2] + (q[2] - p[2]) / n * s})) ++c.hanging;
    }
  }
  return c;
}

void expect_conforming(const Volume& v, const TetGrid& g, const std::string& what) {
  const Conformity c = conformity(v, g);
  EXPECT_EQ(c.nonpositive, 0u) << what;
  EXPECT_EQ(c.unpaired_interior, 0u) << what;
  EXPECT_EQ(c.same_orientation, 0u) << what;
  EXPECT_EQ(c.shared_by_more, 0u) << what;
  EXPECT_EQ(c.hanging, 0u) << what;
  EXPECT_EQ(c.unused_vertices, 0u) << what;
  EXPECT_TRUE(c.volume_is_box) << what;
}

Volume random_volume(Dims d, std::mt19937& rng, int levels) {
  Volume v = make_volume(d, ScalarType::f32);
  for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, double(rng() % levels));
  return v;
}

BisectionGrid grid_of(const Volume& v, double max_error) {
  BisectionOptions o;
  o.max_error = max_error;
  return bisection_grid(v, value_range(v), o);
}

}  // namespace

TEST(Bisection, EveryVoxelWithinTheBoundAndConformingOverSizesAndShapes) {
  // Sizes 2…65 and slabs; odd, even, 2^k and 2^k+1 extents; bounds from 0 to the whole range.
  std::mt19937 rng(3);
  const std::vector<Dims> shapes = {{2, 2, 2},  {3, 3, 3},  {5, 5, 5},  {17, 17, 17}, {33, 33, 33}, {16, 16, 16}, {2, 9, 5},
                                    {17, 3, 9}, {2, 40, 7}, {33, 2, 2}, {6, 11, 4},   {9, 9, 2},    {64, 7, 3},   {65, 5, 6}};
  for (const Dims& d : shapes)
    for (double bound : {0.0, 0.5, 2.0, 4.5, 100.0}) {
      const Volume v = random_volume(d, rng, 1 + static_cast<int>(rng() % 6));
      const BisectionGrid b = grid_of(v, bound);
      const std::string what = fmt::format("{}x{}x{} bound {}", d[0], d[1], d[2], bound);
      EXPECT_LE(b.error_bound, std::max(bound, 0.0) + 1e-12) << what;
      const Check c = brute_force(v, b.grid);
      EXPECT_EQ(c.uncovered, 0) << what;
      EXPECT_LE(c.max_error, b.error_bound + 1e-9) << what;
      expect_conforming(v, b.grid, what);
    }
}

TEST(Bisection, AnalyticFieldsAndAnisotropicSpacingKeepTheBound) {
  for (const char* name : {"sphere", "marschner-lobb", "torus"})
    for (std::int64_t n : {17, 24, 33}) {
      Volume v = make_synthetic(name, n, ScalarType::f32);
      v.spacing = {0.5, 1.25, 3.0};  // index space is what is bisected: the guarantee is unchanged
      const ValueRange r = value_range(v);
      for (double rel : {0.01, 0.05, 0.2}) {
        const BisectionGrid b = grid_of(v, rel * (r.max - r.min));
        const std::string what = fmt::format("{} {} rel {}", name, n, rel);
        const Check c = brute_force(v, b.grid);
        EXPECT_EQ(c.uncovered, 0) << what;
        EXPECT_LE(c.max_error, b.error_bound * (1 + 1e-12)) << what;
        EXPECT_LE(b.error_bound, rel * (r.max - r.min)) << what;
        // The library's own measurement agrees with the brute force.
        EXPECT_NEAR(piecewise_linear_error(v, b.grid).max, c.max_error, 1e-6 * (r.max - r.min)) << what;
        expect_conforming(v, b.grid, what);
      }
    }
}

TEST(Bisection, RealVolumeCropKeepsTheBound) {
  REQUIRE_DATA(data);
  const Volume full = read_volume(data + "/ct_chest_lidc2.nhdr");
  Volume v = make_volume({41, 37, 23}, full.type);  // odd sizes through the heart
  for (std::int64_t z = 0; z < 23; ++z)
    for (std::int64_t y = 0; y < 37; ++y)
      for (std::int64_t x = 0; x < 41; ++x) v.set(v.index(x, y, z), full.at(100 + x, 110 + y, 60 + z));
  for (double bound : {0.0, 3.0, 10.0, 40.0}) {
    const BisectionGrid b = grid_of(v, bound);
    const Check c = brute_force(v, b.grid);
    EXPECT_EQ(c.uncovered, 0) << bound;
    EXPECT_LE(c.max_error, b.error_bound) << bound;
    expect_conforming(v, b.grid, fmt::format("chest crop bound {}", bound));
  }
}

TEST(Bisection, LinearFieldGivesTheCoarsestMeshAtErrorZero) {
  for (Dims d : {Dims{17, 17, 17}, Dims{33, 33, 33}, Dims{20, 13, 9}}) {
    Volume v = make_volume(d, ScalarType::f64);
    for (std::int64_t z = 0; z < d[2]; ++z)
      for (std::int64_t y = 0; y < d[1]; ++y)
        for (std::int64_t x = 0; x < d[0]; ++x) v.set(v.index(x, y, z), 1.0 * x + 2.0 * y + 3.0 * z);
    const BisectionGrid exact = grid_of(v, 0);
    const BisectionGrid coarsest = grid_of(v, 1e300);  // only the splits the box forces
    EXPECT_EQ(exact.grid.tets, coarsest.grid.tets) << d[0];
    EXPECT_LE(brute_force(v, exact.grid).max_error, 1e-9);
    if (d[0] == d[1] && d[1] == d[2] && std::has_single_bit(static_cast<std::uint64_t>(d[0] - 1))) {
      EXPECT_EQ(exact.grid.tet_count(), 6u) << "a 2^k+1 cube is the 6 root tetrahedra";
    }
  }
}

TEST(Bisection, NoiseAtErrorZeroKeepsEveryVoxel) {
  for (Dims d : {Dims{9, 9, 9}, Dims{12, 7, 5}, Dims{17, 2, 17}}) {
    std::mt19937 rng(1);
    Volume v = make_volume(d, ScalarType::f32);
    for (std::int64_t i = 0; i < v.voxel_count(); ++i) v.set(i, std::uniform_real_distribution<double>(0, 1000)(rng));
    const BisectionGrid b = grid_of(v, 0);
    EXPECT_EQ(b.grid.vertex_count(), static_cast<std::size_t>(v.voxel_count()));
    EXPECT_EQ(b.grid.tet_count(), static_cast<std::size_t>(6 * (d[0] - 1) * (d[1] - 1) * (d[2] - 1)));  // every unit cube
    EXPECT_LE(brute_force(v, b.grid).max_error, 1e-9);
  }
}

TEST(Bisection, CellFloorKeepsCubesWholeConformingAndWithinItsMeasuredBound) {
  // The viewer's coarse levels: no diamond split below cubes of 2^f voxels but where the box
  // forces it. Noise at bound 0 splits every diamond of the fine grid that covers more than a few
  // voxels, so on a 2^k+1 cube the floored grid is exactly the Kuhn tetrahedra of the cubes of
  // side 2^f; on other boxes it is checked for
  // conformity, coverage and its measured bound voxel by voxel.
  std::mt19937 rng(7);
  for (Dims d : {Dims{17, 17, 17}, Dims{33, 33, 33}, Dims{40, 23, 17}, Dims{9, 33, 5}, Dims{33, 2, 9}}) {
    const Volume noise = random_volume(d, rng, 50);
    const BisectionGrid fine = grid_of(noise, 0);
    std::size_t previous_tets = fine.grid.tet_count();
    double previous_bound = 0;
    for (int f = 0; f <= 3; ++f) {
      BisectionOptions o;
      o.max_error = 0;
      o.cell_floor = f;
      const BisectionGrid b = bisection_coarsen(fine.grid, fine.hierarchy, o);
      const std::string what = fmt::format("{}x{}x{} floor {}", d[0], d[1], d[2], f);
      const Check c = brute_force(noise, b.grid);
      EXPECT_EQ(c.uncovered, 0) << what;
      EXPECT_LE(c.max_error, b.error_bound * (1 + 1e-12)) << what;
      EXPECT_LE(b.error_bound, 1.5 * c.max_error + 1e-9) << what << ": the measured bound is not far above the error";
      expect_conforming(noise, b.grid, what);
      EXPECT_LE(b.grid.tet_count(), previous_tets) << what;
      EXPECT_GE(b.error_bound, previous_bound) << what;
      previous_tets = b.grid.tet_count();
      previous_bound = b.error_bound;
      if (f == 0) {
        EXPECT_EQ(b.grid.tets, fine.grid.tets) << what;
        EXPECT_EQ(b.error_bound, fine.error_bound) << what;
      }
      const std::int64_t n = d[0] - 1, cells = n >> f;
      if (f > 0 && d[1] == d[0] && d[2] == d[0] && std::has_single_bit(static_cast<std::uint64_t>(n))) {
        EXPECT_EQ(b.grid.tet_count(), static_cast<std::size_t>(6 * cells * cells * cells)) << what;
        for (const auto& p : b.grid.ijk) EXPECT_EQ((p[0] | p[1] | p[2]) & ((1u << f) - 1), 0u) << what;
      }
    }
  }
  // On a smooth field the floor only removes detail: never more tetrahedra than without it.
  const Volume sphere = make_synthetic("sphere", 33, ScalarType::f32);
  const ValueRange r = value_range(sphere);
  const BisectionGrid fine = grid_of(sphere, 0.002 * (r.max - r.min));
  for (double rel : {0.002, 0.02})
    for (int f = 1; f <= 3; ++f) {
      BisectionOptions o;
      o.max_error = rel * (r.max - r.min);
      const BisectionGrid plain = bisection_coarsen(fine.grid, fine.hierarchy, o);
      o.cell_floor = f;
      const BisectionGrid b = bisection_coarsen(fine.grid, fine.hierarchy, o);
      EXPECT_LE(b.grid.tet_count(), plain.grid.tet_count()) << rel << " floor " << f;
      EXPECT_GE(b.error_bound, plain.error_bound);
      EXPECT_LE(brute_force(sphere, b.grid).max_error, b.error_bound * (1 + 1e-12));
      expect_conforming(sphere, b.grid, fmt::format("sphere {} floor {}", rel, f));
    }
  // With the displacement criterion too: both bounds measured, the error one voxel by voxel.
  {
    BisectionOptions o;
    o.max_error = 0.002 * (r.max - r.min);
    o.max_displacement = 0.25;
    const BisectionGrid moved = bisection_grid(sphere, r, o);
    o.cell_floor = 2;
    const BisectionGrid b = bisection_coarsen(moved.grid, moved.hierarchy, o);
    EXPECT_LT(b.grid.tet_count(), moved.grid.tet_count());
    EXPECT_GE(b.displacement_bound, moved.displacement_bound);
    EXPECT_LE(brute_force(sphere, b.grid).max_error, b.error_bound * (1 + 1e-12));
    expect_conforming(sphere, b.grid, "sphere with displacement, floor 2");
  }
  // Only a coarsening takes a floor, and a sane one.
  BisectionOptions bad;
  bad.cell_floor = 2;
  EXPECT_THROW(bisection_select(sphere, r, bisection_errors(sphere, r), bad), OptionError);
  for (int f : {-1, 31}) {
    bad.cell_floor = f;
    EXPECT_THROW(bisection_coarsen(fine.grid, fine.hierarchy, bad), OptionError);
  }
}

TEST(Bisection, FlatVolumesAreRefused) {
  for (Dims d : {Dims{1, 5, 5}, Dims{5, 1, 5}, Dims{5, 5, 1}, Dims{1, 1, 1}}) {
    const Volume v = make_volume(d, ScalarType::u8);
    EXPECT_THROW(grid_of(v, 0), InputError);
  }
  const Volume v = make_volume({4, 4, 4}, ScalarType::u8);
  EXPECT_THROW(grid_of(v, -1), OptionError);
  EXPECT_THROW(grid_of(v, std::nan("")), OptionError);
}

TEST(Bisection, DiamondParentsAndChildrenMatchTheHierarchyBuiltTetByTet) {
  // Bisect the 6 root tetrahedra of cubes of side 2, 4, 8, 16 all the way down; every tetrahedron
  // with a lattice midpoint belongs to the diamond centred there. A diamond's parents are the
  // midpoints of its tetrahedra's parents, its children the midpoints of their halves.
  using detail::Coord;
  for (int k = 1; k <= 4; ++k) {
    const std::int32_t S = 1 << k;
    std::map<Coord, std::set<Coord>> parents, kids;
    std::map<Coord, int> members;
    std::vector<std::pair<std::array<Coord, 4>, Coord>> stack;  // tetrahedron, parent's midpoint
    const Coord none{-1, -1, -1};
    const int perms[6][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1}, {0, 2, 1}, {2, 1, 0}, {1, 0, 2}};
    for (const auto& p : perms) {
      Coord v1{0, 0, 0};
      v1[p[0]] = S;
      Coord v2 = v1;
      v2[p[1]] = S;
      stack.push_back({{Coord{0, 0, 0}, v1, v2, Coord{S, S, S}}, none});
    }
    while (!stack.empty()) {
      auto [t, from] = stack.back();
      stack.pop_back();
      // The longest edge (unique), by brute force.
      std::int64_t best = -1;
      int bi = 0, bj = 0, ties = 0;
      for (int i = 0; i < 4; ++i)
        for (int j = i + 1; j < 4; ++j) {
          std::int64_t len = 0;
          for (int a = 0; a < 3; ++a) len += std::int64_t(t[i][a] - t[j][a]) * (t[i][a] - t[j][a]);
          if (len > best)
            best = len, bi = i, bj = j, ties = 0;
          else if (len == best)
            ++ties;
        }
      ASSERT_EQ(ties, 0) << "the longest edge is unique";
      if ((t[bi][0] + t[bj][0]) % 2 || (t[bi][1] + t[bj][1]) % 2 || (t[bi][2] + t[bj][2]) % 2) continue;
      const Coord m{(t[bi][0] + t[bj][0]) / 2, (t[bi][1] + t[bj][1]) / 2, (t[bi][2] + t[bj][2]) / 2};
      ++members[m];
      if (from != none) {
        parents[m].insert(from);
        kids[from].insert(m);
      }
      auto a = t, b = t;
      a[bj] = m;
      b[bi] = m;
      stack.push_back({a, m});
      stack.push_back({b, m});
    }
    for (std::int32_t z = 0; z <= S; ++z)
      for (std::int32_t y = 0; y <= S; ++y)
        for (std::int32_t x = 0; x <= S; ++x) {
          const Coord c{x, y, z};
          const detail::Diamond d = detail::classify(c, k);
          ASSERT_EQ(d.valid, members.count(c) == 1) << x << "," << y << "," << z;
          if (!d.valid) continue;
          // Members: 6, 4 or 8 tetrahedra where the root cube holds them all.
          Coord cubes[4];
          const int n_cubes = detail::diamond_cubes(d, S, cubes);
          const int per_cube = d.kind == detail::DiamondKind::cube ? 6 : 2;
          EXPECT_EQ(members[c], n_cubes * per_cube) << x << "," << y << "," << z;
          Coord out[8];
          std::set<Coord> got;
          for (int i = 0, n = detail::parents(d, S, out); i < n; ++i)
            if (detail::classify(out[i], k).valid) got.insert(out[i]);
          EXPECT_EQ(got, parents[c]) << "parents of " << x << "," << y << "," << z;
          got.clear();
          for (int i = 0, n = detail::children(d, S, out); i < n; ++i) got.insert(out[i]);
          EXPECT_EQ(got, kids[c]) << "children of " << x << "," << y << "," << z;
          // Its refinement edge is the longest edge of every member (checked through the midpoint above).
          const auto [p, q] = detail::refinement_edge(d);
          EXPECT_EQ((Coord{(p[0] + q[0]) / 2, (p[1] + q[1]) / 2, (p[2] + q[2]) / 2}), c);
        }
  }
}

TEST(Bisection, MaubachOrderNamesTheLongestEdgeAtEveryNode) {
  // The walk finds a tetrahedron's refinement edge from Maubach's vertex order instead of edge
  // lengths. Against brute force, at every node of the hierarchies of cubes of side 2 to 32: the
  // edge it names is the unique longest one, and the halves' orders follow.
  using detail::Coord;
  using detail::OrderState;
  using detail::Tet;
  for (int k = 1; k <= 5; ++k) {
    const std::int32_t S = 1 << k;
    std::vector<std::pair<Tet, OrderState>> stack;
    const auto roots = detail::root_tetrahedra(S);
    for (int r = 0; r < 6; ++r) stack.push_back({roots[static_cast<std::size_t>(r)], detail::root_order(r)});
    std::size_t nodes = 0;
    while (!stack.empty()) {
      auto [t, o] = stack.back();
      stack.pop_back();
      std::int64_t best = -1;
      int bi = 0, bj = 0;
      for (int i = 0; i < 4; ++i)
        for (int j = i + 1; j < 4; ++j) {
          std::int64_t len = 0;
          for (int a = 0; a < 3; ++a) len += std::int64_t(t[i][a] - t[j][a]) * (t[i][a] - t[j][a]);
          if (len > best) best = len, bi = i, bj = j;
        }
      const bool lattice = (t[bi][0] + t[bj][0]) % 2 == 0 && (t[bi][1] + t[bj][1]) % 2 == 0 && (t[bi][2] + t[bj][2]) % 2 == 0;
      Coord m;
      int i = -1, j = -1;
      ASSERT_EQ(detail::refinement(t, o, m, i, j), lattice);
      if (!lattice) continue;
      ++nodes;
      ASSERT_EQ(i, bi);
      ASSERT_EQ(j, bj);
      ASSERT_EQ(m, (Coord{(t[bi][0] + t[bj][0]) / 2, (t[bi][1] + t[bj][1]) / 2, (t[bi][2] + t[bj][2]) / 2}));
      Tet a = t, b = t;
      a[bj] = m;
      b[bi] = m;
      const auto h = detail::halves(t, o, m, i, j);
      ASSERT_EQ(h[0].tet, a);
      ASSERT_EQ(h[1].tet, b);
      stack.push_back({a, h[0].order});
      stack.push_back({b, h[1].order});
    }
    EXPECT_GT(nodes, std::size_t(6) << (3 * k - 1)) << "every level was visited";
  }
}

TEST(Bisection, ErrorCodesAreConservativeAndMonotone) {
  ErrorCodes codes;
  codes.scale = 4095;
  codes.zero = 1e-12;
  std::mt19937 rng(5);
  std::uint8_t previous = 0;
  for (double e = 1e-13; e < 1e5; e *= 1.01) {
    const std::uint8_t c = codes.code(e);
    EXPECT_GE(codes.error(c), std::min(e, codes.scale)) << e;  // never smaller than the error it stands for
    if (c > 0 && c < 254) {
      EXPECT_LT(codes.error(c - 1), e) << e;  // and the smallest such code
    }
    EXPECT_GE(c, previous);
    previous = c;
  }
  EXPECT_EQ(codes.code(0), 0);
  EXPECT_EQ(codes.code(std::numeric_limits<double>::infinity()), ErrorCodes::kForced);
  for (double bound : {0.0, 0.3, 1.0, 17.0, 4000.0, 1e9}) {
    const std::uint8_t t = codes.threshold(bound);
    EXPECT_LE(codes.error(t), std::max(bound, codes.zero));
    if (t < 254) {
      EXPECT_GT(codes.error(t + 1), bound);
    }
  }
}

TEST(Bisection, SameGridForAnyThreadCount) {
  const Volume v = make_synthetic("marschner-lobb", 70, ScalarType::f32);
  BisectionGrid one, four;
  tbb::task_arena(1).execute([&] { one = grid_of(v, 0.02); });
  tbb::task_arena(4).execute([&] { four = grid_of(v, 0.02); });
  EXPECT_EQ(one.grid.tets, four.grid.tets);
  EXPECT_EQ(one.grid.ijk, four.grid.ijk);
  EXPECT_EQ(one.hierarchy.error_code, four.hierarchy.error_code);
}

TEST(Bisection, SphereSurfaceIsClosedManifoldWithEulerCharacteristicTwo) {
  for (std::int64_t n : {24, 50, 64}) {
    const Volume v = make_synthetic("sphere", n, ScalarType::i16);
    PrepareOptions o;
    o.max_error = 0.05;
    o.relative = true;
    auto p = std::make_shared<const PreparedGrid>(prepare(v, o));
    for (double iso : {600.0, 700.0, 900.0}) {  // r = R·1000/iso stays inside the box (R = n/4)
      Extractor ex(p);
      ex.extract(iso);
      const auto census = testutil::edge_census(ex.mesh(), v.dims, v.spacing);
      EXPECT_GT(ex.mesh().triangle_count(), 0u);
      EXPECT_EQ(census.boundary, 0u) << n << " " << iso;
      EXPECT_EQ(census.nonmanifold, 0u) << n << " " << iso;
      EXPECT_EQ(census.misoriented, 0u) << n << " " << iso;
      EXPECT_EQ(census.degenerate, 0u) << n << " " << iso;
      EXPECT_EQ(census.euler, 2) << n << " " << iso;
    }
  }
}

TEST(Bisection, DisplacementCriterionHoldsTetrahedronByTetrahedron) {
  // Every tetrahedron of the grid: its largest error at a voxel it holds, against D times the
  // smallest gradient magnitude (central differences, one-sided at the border, floored at 1 % of
  // the range per voxel) at the voxels it holds that are not its vertices.
  Volume v = make_synthetic("marschner-lobb", 29, ScalarType::f32);
  v.spacing = {1, 1, 2};
  const ValueRange r = value_range(v);
  const double g0 = 0.01 * (r.max - r.min);
  auto gradient = [&](std::int64_t x, std::int64_t y, std::int64_t z) {
    const std::int64_t p[3] = {x, y, z};
    double sq = 0;
    for (int a = 0; a < 3; ++a) {
      std::int64_t lo[3] = {x, y, z}, hi[3] = {x, y, z};
      double span = 2;
      if (p[a] == 0)
        lo[a] = p[a], hi[a] = p[a] + 1, span = 1;
      else if (p[a] == v.dims[a] - 1)
        lo[a] = p[a] - 1, hi[a] = p[a], span = 1;
      else
        lo[a] = p[a] - 1, hi[a] = p[a] + 1;
      const double d = (v.at(hi[0], hi[1], hi[2]) - v.at(lo[0], lo[1], lo[2])) / span;
      sq += d * d;
    }
    return std::sqrt(sq);
  };
  std::size_t previous = 0;
  for (double D : {2.0, 0.5, 0.1}) {
    BisectionOptions o;
    o.max_error = std::numeric_limits<double>::infinity();
    o.max_displacement = D;
    const BisectionGrid b = bisection_grid(v, r, o);
    expect_conforming(v, b.grid, fmt::format("D {}", D));
    EXPECT_LE(b.displacement_bound, D);
    EXPECT_GT(b.grid.tet_count(), previous) << "a smaller displacement needs more tetrahedra";
    previous = b.grid.tet_count();
    std::size_t checked = 0;
    for (const auto& t : b.grid.tets) {
      const I3 P[4] = {at(b.grid, t[0]), at(b.grid, t[1]), at(b.grid, t[2]), at(b.grid, t[3])};
      const std::int64_t Dt = det(P[0], P[1], P[2], P[3]);
      I3 lo = P[0], hi = P[0];
      for (const auto& p : P)
        for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
      double worst = 0, gmin = std::numeric_limits<double>::infinity();
      for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
        for (std::int64_t y = lo[1]; y <= hi[1]; ++y)
          for (std::int64_t x = lo[0]; x <= hi[0]; ++x) {
            const I3 q{x, y, z};
            const std::int64_t l[4] = {det(q, P[1], P[2], P[3]), det(P[0], q, P[2], P[3]), det(P[0], P[1], q, P[3]),
                                       det(P[0], P[1], P[2], q)};
            if (l[0] < 0 || l[1] < 0 || l[2] < 0 || l[3] < 0) continue;
            if (std::count(l, l + 4, Dt) == 1) continue;  // a vertex: no error there
            double rec = 0;
            for (int i = 0; i < 4; ++i) rec += static_cast<double>(l[i]) / static_cast<double>(Dt) * b.grid.values[t[i]];
            worst = std::max(worst, std::abs(v.at(x, y, z) - rec));
            gmin = std::min(gmin, gradient(x, y, z));
            ++checked;
          }
      ASSERT_LE(worst, D * std::max(gmin, g0) * (1 + 1e-6) + 1e-9) << "D " << D;
    }
    EXPECT_GT(checked, 0u);
  }
}
