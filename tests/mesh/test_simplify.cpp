// Simplification to a distance (simplify.hpp): closed surfaces stay closed, 2-manifold and
// oriented with their Euler characteristic, stay within the distance of the extracted surface and
// of the analytic one, lose triangles as the distance grows; open surfaces keep their border on
// the volume's box.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <functional>
#include <memory>
#include <set>

#include "adaptiso/extractor.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/simplify.hpp"
#include "adaptiso/surface_distance.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

namespace {

Mesh extracted(const Volume& v, double iso) {
  PrepareOptions o;
  o.max_error = 0.005;
  o.relative = true;
  Extractor ex(std::make_shared<const PreparedGrid>(prepare(v, o)));
  ex.extract(iso);
  return ex.mesh();
}

// The mean and the largest analytic distance over the vertices and triangle centroids of a mesh.
std::pair<double, double> analytic(const Mesh& m, const std::function<double(double, double, double)>& distance) {
  double w = 0, sum = 0;
  for (const auto& p : m.positions) {
    const double d = std::abs(distance(p[0], p[1], p[2]));
    w = std::max(w, d), sum += d;
  }
  for (const auto& t : m.triangles) {
    double c[3];
    for (int a = 0; a < 3; ++a) c[a] = (m.positions[t[0]][a] + m.positions[t[1]][a] + m.positions[t[2]][a]) / 3.0;
    const double d = std::abs(distance(c[0], c[1], c[2]));
    w = std::max(w, d), sum += d;
  }
  return {sum / static_cast<double>(m.vertex_count() + m.triangle_count()), w};
}

}  // namespace

TEST(Simplify, ClosedSurfacesStayClosedManifoldAndWithinTheDistance) {
  const std::int64_t n = 48;
  const double c = (n - 1) / 2.0;
  struct Case {
    const char* name;
    double iso;
    long long euler;
    std::function<double(double, double, double)> distance;
  };
  const double R = n / 4.0 * 1000 / 700;  // the sphere's radius at iso 700
  const double Rm = n / 4.0, rm = n / 10.0;
  const std::vector<Case> cases = {
      {"sphere", 700, 2, [&](double x, double y, double z) { return std::hypot(x - c, y - c, z - c) - R; }},
      {"torus", 500, 0, [&](double x, double y, double z) { return std::hypot(std::hypot(x - c, y - c) - Rm, z - c) - rm; }}};
  // One pass over the whole mesh, and the same mesh cut into chunks simplified in parallel.
  for (const std::size_t chunk : {kSimplifyChunkTriangles, std::size_t{1500}})
    for (const auto& k : cases) {
      const Volume v = make_synthetic(k.name, n, ScalarType::f32);
      const Mesh m = extracted(v, k.iso);
      SCOPED_TRACE(::testing::Message() << "chunks of " << chunk << " triangles, " << m.triangle_count() << " in all");
      const auto [base_mean, base_max] = analytic(m, k.distance);
      std::size_t previous = m.triangle_count();
      for (double d : {0.1, 0.25, 0.5, 1.0}) {
        SimplifyStats st;
        const Mesh s = simplify_mesh(m, d, &st, chunk);
        EXPECT_EQ(st.chunks > 1, chunk < m.triangle_count());
        const auto census = testutil::edge_census(s, v.dims, v.spacing);
        EXPECT_EQ(census.boundary, 0u) << k.name << " D " << d;
        EXPECT_EQ(census.nonmanifold, 0u) << k.name << " D " << d;
        EXPECT_EQ(census.misoriented, 0u) << k.name << " D " << d;
        EXPECT_EQ(census.degenerate, 0u) << k.name << " D " << d;
        EXPECT_EQ(census.euler, k.euler) << k.name << " D " << d;
        EXPECT_EQ(st.triangles_after, s.triangle_count());
        EXPECT_LT(s.triangle_count(), previous) << k.name << " D " << d;
        previous = s.triangle_count();
        // The mean distance to the analytic surface grows by at most D. meshoptimizer's error is a
        // quadric estimate, not a strict bound on the largest deviation: that grew by up to 1.37 D.
        const auto [mean, max] = analytic(s, k.distance);
        EXPECT_LE(mean, base_mean + d) << k.name << " D " << d;
        EXPECT_LE(max, base_max + 1.5 * d) << k.name << " D " << d;
        const SurfaceDistance sd = surface_distance(s, m);
        EXPECT_LE(0.5 * (sd.a_to_b.mean + sd.b_to_a.mean), d) << k.name << " D " << d;
        EXPECT_EQ(s.normals.size(), s.vertex_count());
      }
      EXPECT_LT(previous, m.triangle_count() / 4) << k.name;
    }
}

TEST(Simplify, OpenSurfaceKeepsItsBorderOnTheBox) {
  const Volume v = make_synthetic("linear", 20, ScalarType::f32);  // a plane through the box
  const Mesh m = extracted(v, 57.0);
  const Mesh s = simplify_mesh(m, 1.0);
  const auto before = testutil::edge_census(m, v.dims, v.spacing), after = testutil::edge_census(s, v.dims, v.spacing);
  ASSERT_GT(before.boundary, 0u);
  EXPECT_TRUE(after.boundary_on_box);
  EXPECT_EQ(after.boundary, before.boundary);  // every border edge kept (its vertices are locked)
  EXPECT_EQ(after.nonmanifold + after.misoriented + after.degenerate, 0u);
  EXPECT_LT(s.triangle_count(), m.triangle_count());
  std::set<std::array<float, 3>> kept(s.positions.begin(), s.positions.end());
  for (const auto& p : m.positions) {
    bool on_box = false;
    for (int a = 0; a < 3; ++a) on_box |= p[a] == 0.0f || p[a] == float(v.dims[a] - 1);
    if (on_box) EXPECT_TRUE(kept.count(p)) << "a border vertex moved";
  }
}

TEST(Simplify, ChunkedOutputIsTheSameForAnyThreadCount) {
  const Mesh m = extracted(make_synthetic("torus", 40, ScalarType::f32), 500);
  const Mesh many = simplify_mesh(m, 0.25, nullptr, 1000);
  Mesh one;
  {
    tbb::global_control only(tbb::global_control::max_allowed_parallelism, 1);
    one = simplify_mesh(m, 0.25, nullptr, 1000);
  }
  EXPECT_EQ(many.triangles, one.triangles);
  EXPECT_EQ(many.positions, one.positions);
  EXPECT_EQ(many.normals, one.normals);
}

TEST(Simplify, ZeroDistanceIsTheMeshAndBadDistancesAreRefused) {
  const Mesh m = extracted(make_synthetic("sphere", 20, ScalarType::i16), 700);
  const Mesh s = simplify_mesh(m, 0);
  EXPECT_EQ(s.triangles, m.triangles);
  EXPECT_EQ(s.positions, m.positions);
  EXPECT_THROW(simplify_mesh(m, -1), OptionError);
  EXPECT_THROW(simplify_mesh(m, std::nan("")), OptionError);
}
