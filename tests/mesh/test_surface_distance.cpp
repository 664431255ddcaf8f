// Surface distance against exact answers: a plane and its offset, concentric spheres.
#include <gtest/gtest.h>

#include <cmath>

#include "adaptiso/surface_distance.hpp"
#include "test_util.hpp"

using namespace adaptiso;

// ---- surface distance against analytic cases ----

namespace {

// A UV sphere of radius r: vertices exactly on the sphere.
Mesh uv_sphere(double r, int n) {
  Mesh m;
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j < 2 * n; ++j) {
      double th = M_PI * i / n, ph = M_PI * j / n;
      m.positions.push_back({float(r * std::sin(th) * std::cos(ph)), float(r * std::sin(th) * std::sin(ph)), float(r * std::cos(th))});
    }
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < 2 * n; ++j) {
      std::uint32_t a = i * 2 * n + j, b = i * 2 * n + (j + 1) % (2 * n), c = a + 2 * n, d = b + 2 * n;
      if (i > 0) m.triangles.push_back({a, c, b});
      if (i + 1 < n) m.triangles.push_back({b, c, d});
    }
  return m;
}

Mesh square(double z, int n) {
  Mesh m;
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) m.positions.push_back({float(i) / n, float(j) / n, float(z)});
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      std::uint32_t a = j * (n + 1) + i;
      m.triangles.push_back({a, a + 1, a + n + 2});
      m.triangles.push_back({a, a + n + 2, a + n + 1});
    }
  return m;
}

}  // namespace

TEST(SurfaceDistance, PlaneAndItsOffset) {
  Mesh a = square(0, 10), b = square(0.25, 7);  // different tessellations, same square
  auto d = surface_distance(a, b);
  for (const auto* s : {&d.a_to_b, &d.b_to_a}) {
    EXPECT_NEAR(s->mean, 0.25, 1e-6);
    EXPECT_NEAR(s->rms, 0.25, 1e-6);
    EXPECT_NEAR(s->p95, 0.25, 1e-6);
    EXPECT_NEAR(s->max, 0.25, 1e-6);
    EXPECT_GE(s->samples, 200'000u);
  }
}

TEST(SurfaceDistance, ConcentricSpheres) {
  // Finely tessellated spheres of radius 10 and 10.5: every distance is close to 0.5 (the chordal
  // error of the tessellation is about 0.002 at this resolution).
  // The default sampling is PlaneAndItsOffset's; here the tessellations' own 4 samples a triangle
  // (80,000 and 64,800) suffice.
  Mesh a = uv_sphere(10, 100), b = uv_sphere(10.5, 90);
  DistanceOptions sampling;
  sampling.min_samples = 1;
  auto d = surface_distance(a, b, sampling);
  EXPECT_NEAR(d.a_to_b.mean, 0.5, 0.005);
  EXPECT_NEAR(d.b_to_a.mean, 0.5, 0.005);
  EXPECT_NEAR(d.a_to_b.max, 0.5, 0.005);
  EXPECT_NEAR(d.b_to_a.max, 0.5, 0.01);
  EXPECT_NEAR(d.hausdorff(), 0.5, 0.01);
  // A surface against itself: zero.
  auto z = surface_distance(a, a, sampling);
  EXPECT_LT(z.a_to_b.max, 1e-5);
  EXPECT_THROW(surface_distance(a, Mesh{}), InputError);
}
