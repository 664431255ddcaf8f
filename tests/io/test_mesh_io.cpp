// Mesh files: PLY round trip, STL/OBJ/glTF layouts, damaged files refused.
#include <gtest/gtest.h>

#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "adaptiso/extractor.hpp"
#include "adaptiso/mesh_io.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

TEST(MeshFiles, PlyRoundTripAndOtherFormats) {
  testutil::TempDir t("mesh");
  Volume v = make_synthetic("sphere", 20, ScalarType::i16);
  TetGrid g = testutil::build_grid(v, testutil::all_voxels(v));
  IntervalTree tree = build_interval_tree(g);
  Extractor ex(testutil::prepared(g, tree));
  ex.extract(600);
  const Mesh m = ex.mesh();
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
