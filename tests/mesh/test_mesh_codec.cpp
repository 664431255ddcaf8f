// The compact wire encoding of meshes (mesh_codec.hpp): the same triangles, positions within half a
// quantization step, normals within the octahedral grid's angle, and far fewer bytes.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <map>
#include <memory>
#include <set>
#include <thread>

#include "adaptiso/extractor.hpp"
#include "adaptiso/mesh_codec.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/synthetic.hpp"

using namespace adaptiso;

namespace {

Mesh sphere_mesh(std::int64_t n) {
  const Volume v = make_synthetic("sphere", n, ScalarType::i16);
  PrepareOptions o;
  o.max_error = 0.01;
  o.relative = true;
  Extractor ex(std::make_shared<const PreparedGrid>(prepare(v, o)));
  ex.extract(700);
  return ex.mesh();
}

// A plane of w × h unit squares, two triangles each, row by row (neighbouring rows share vertices).
Mesh plane_mesh(std::uint32_t w, std::uint32_t h) {
  Mesh m;
  for (std::uint32_t y = 0; y <= h; ++y)
    for (std::uint32_t x = 0; x <= w; ++x) {
      m.positions.push_back({static_cast<float>(x), static_cast<float>(y), 0});
      m.normals.push_back({0, 0, 1});
    }
  for (std::uint32_t y = 0; y < h; ++y)
    for (std::uint32_t x = 0; x < w; ++x) {
      const std::uint32_t a = y * (w + 1) + x;
      m.triangles.push_back({a, a + 1, a + w + 2});
      m.triangles.push_back({a, a + w + 2, a + w + 1});
    }
  return m;
}

}  // namespace

TEST(MeshCodec, RoundTripKeepsTrianglesWithinTheQuantization) {
  const Mesh m = sphere_mesh(48);
  ASSERT_GT(m.triangle_count(), 1000u);
  const std::string bytes = encode_mesh_compact(m);
  const Mesh d = decode_mesh_compact(bytes);
  ASSERT_EQ(d.triangle_count(), m.triangle_count());
  ASSERT_EQ(d.vertex_count(), m.vertex_count());  // every vertex is used
  float lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = m.positions[0][a];
  for (const auto& p : m.positions)
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], p[a]), hi[a] = std::max(hi[a], p[a]);
  // Triangle by triangle (the decoder numbers vertices by first use, and the index codec may
  // rotate a triangle's corners, keeping its winding): each corner within half a step of the
  // original, each normal within 1°.
  const double step = 0.5 * 1.001 / 65535;
  auto near = [&](const std::array<float, 3>& p, const std::array<float, 3>& q) {
    for (int a = 0; a < 3; ++a)
      if (std::abs(p[a] - q[a]) > step * (hi[a] - lo[a]) + 1e-6) return false;
    return true;
  };
  for (std::size_t t = 0; t < m.triangle_count(); ++t) {
    int rotation = -1;
    for (int r = 0; r < 3 && rotation < 0; ++r) {
      bool all = true;
      for (int k = 0; k < 3; ++k) all = all && near(m.positions[m.triangles[t][k]], d.positions[d.triangles[t][(k + r) % 3]]);
      if (all) rotation = r;
    }
    ASSERT_GE(rotation, 0) << "triangle " << t << " moved";
    for (int k = 0; k < 3; ++k) {
      const auto& n = m.normals[m.triangles[t][k]];
      const auto& e = d.normals[d.triangles[t][(k + rotation) % 3]];
      const double dot = n[0] * e[0] + n[1] * e[1] + n[2] * e[2];
      const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
      ASSERT_GT(dot / len, std::cos(1.0 * M_PI / 180));
    }
  }
  // Far below the 24 bytes a vertex and 12 a triangle of the plain layout.
  const double plain = 24.0 * m.vertex_count() + 12.0 * m.triangle_count();
  EXPECT_LT(static_cast<double>(bytes.size()), plain / 3) << bytes.size() / static_cast<double>(m.triangle_count()) << " bytes a triangle";
}

TEST(MeshCodec, EmptyMeshAndMalformedBuffersAreHandled) {
  const Mesh empty;
  const Mesh d = decode_mesh_compact(encode_mesh_compact(empty));
  EXPECT_EQ(d.triangle_count(), 0u);
  EXPECT_EQ(d.vertex_count(), 0u);
  Mesh points;  // vertices without triangles (UBSan caught &triangles[0][0] on an empty vector)
  points.positions = {{0, 0, 0}, {1, 2, 3}};
  points.normals = {{0, 0, 1}, {0, 1, 0}};
  EXPECT_EQ(decode_mesh_compact(encode_mesh_compact(points)).vertex_count(), 0u);  // unused vertices are not sent
  const std::string good = encode_mesh_compact(sphere_mesh(20));
  EXPECT_THROW(decode_mesh_compact(good.substr(0, good.size() - 5)), InputError);
  EXPECT_THROW(decode_mesh_compact("ADM0" + good.substr(4)), InputError);
  std::string huge = good;
  huge[4] = huge[5] = huge[6] = huge[7] = '\xff';  // a vertex count the streams cannot hold
  EXPECT_THROW(decode_mesh_compact(huge), InputError);
  for (std::size_t cut = 0; cut < good.size(); cut += 97) EXPECT_THROW(decode_mesh_compact(good.substr(0, cut)), InputError);
}

// The encoder keeps its working arrays for the next call (the viewer's surfaces are millions of
// triangles): a large mesh, a small one and the large again give the bytes of fresh encodings, and
// threads encoding different meshes at once each get their own.
TEST(MeshCodec, ReusedWorkingArraysGiveTheSameBytesAlsoFromSeveralThreads) {
  const Mesh large = sphere_mesh(48), small = sphere_mesh(16);
  const std::string a = encode_mesh_compact(large), b = encode_mesh_compact(small);
  EXPECT_EQ(encode_mesh_compact(large), a);
  EXPECT_EQ(encode_mesh_compact(small), b);
  EXPECT_EQ(encode_mesh_compact(large), a);
  Mesh none;
  EXPECT_EQ(decode_mesh_compact(encode_mesh_compact(none)).triangle_count(), 0u);
  EXPECT_EQ(encode_mesh_compact(small), b);
  std::vector<std::thread> threads;
  std::vector<int> wrong(4, 0);
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&, t] {
      for (int k = 0; k < 10; ++k) wrong[static_cast<std::size_t>(t)] += encode_mesh_compact(t % 2 ? small : large) != (t % 2 ? b : a);
    });
  for (auto& th : threads) th.join();
  EXPECT_EQ(wrong, std::vector<int>(4, 0));
}

// Encoding in a given order is encoding the triangles so reordered, byte for byte; an order that
// is not one of the triangles is refused. And the order pays: a sphere whose triangles lie in a
// scattered order takes fewer bytes sent in the march's order (what the viewer does after
// incremental steps).
TEST(MeshCodec, AnOrderEncodesTheTrianglesSoReorderedAndACoherentOneIsSmaller) {
  const Mesh m = sphere_mesh(48);
  const std::size_t T = m.triangle_count();
  std::vector<std::uint32_t> scatter(T);
  for (std::size_t i = 0; i < T; ++i) scatter[i] = static_cast<std::uint32_t>((i * 7919) % T);  // 7919 prime, T not its multiple
  ASSERT_NE(T % 7919, 0u);
  Mesh scattered = m;
  for (std::size_t i = 0; i < T; ++i) scattered.triangles[i] = m.triangles[scatter[i]];
  EXPECT_EQ(encode_mesh_compact(m, scatter), encode_mesh_compact(scattered));
  std::vector<std::uint32_t> back(T);  // the inverse: scattered back into the march's order
  for (std::size_t i = 0; i < T; ++i) back[scatter[i]] = static_cast<std::uint32_t>(i);
  const std::string coherent = encode_mesh_compact(scattered, back);
  EXPECT_EQ(coherent, encode_mesh_compact(m));
  EXPECT_LT(coherent.size() * 3, encode_mesh_compact(scattered).size() * 2);
  EXPECT_THROW(encode_mesh_compact(m, std::vector<std::uint32_t>(T - 1, 0)), std::invalid_argument);
  std::vector<std::uint32_t> outside = back;
  outside[T / 2] = static_cast<std::uint32_t>(T);
  EXPECT_THROW(encode_mesh_compact(m, outside), std::invalid_argument);
  EXPECT_EQ(decode_mesh_compact(encode_mesh_compact(m)).triangle_count(), T);  // the pool's scratch is still sound
}

// Above 2^20 triangles the index goes out as several streams, encoded side by side, each rotated by
// the first vertex it uses first. A plane of 3 streams whose boundaries cut through shared rows,
// then a fourth stream of repeated triangles that uses no new vertex (its base is the vertex
// count): every triangle decodes to its own corners, and one thread encodes the same bytes.
TEST(MeshCodec, ManyIndexStreamsDecodeToTheSameTriangles) {
  Mesh m = plane_mesh(1024, 1025);  // 2,099,200 triangles: 2 full streams and part of a third
  const std::size_t T0 = m.triangle_count();
  const std::size_t streams = 3;
  for (std::size_t t = 0; m.triangle_count() < streams * (std::size_t{1} << 20) + 500; ++t) m.triangles.push_back(m.triangles[t % T0]);
  const std::string bytes = encode_mesh_compact(m);
  const Mesh d = decode_mesh_compact(bytes);
  ASSERT_EQ(d.triangle_count(), m.triangle_count());
  ASSERT_EQ(d.vertex_count(), m.vertex_count());
  const float half_step = 0.5f * 1025.0f / 65535.0f + 1e-3f;  // and float rounding at 1,000
  auto same = [&](const std::array<float, 3>& p, const std::array<float, 3>& q) {
    return std::abs(p[0] - q[0]) <= half_step && std::abs(p[1] - q[1]) <= half_step && p[2] == q[2];
  };
  for (std::size_t t = 0; t < m.triangle_count(); ++t) {
    bool found = false;
    for (int r = 0; r < 3 && !found; ++r) {
      bool all = true;
      for (int k = 0; k < 3; ++k) all = all && same(m.positions[m.triangles[t][k]], d.positions[d.triangles[t][(k + r) % 3]]);
      found = all;
    }
    ASSERT_TRUE(found) << "triangle " << t << " moved";
  }
  // Rotating by the base keeps the streams as small as one: about the bytes of the plane alone.
  EXPECT_LT(static_cast<double>(bytes.size()) / static_cast<double>(m.triangle_count()), 2.5);
  tbb::global_control only(tbb::global_control::max_allowed_parallelism, 1);
  EXPECT_EQ(encode_mesh_compact(m), bytes);
}
