// Global lattice keys (tet_grid.hpp): a vertex is named by its voxel index, an edge by its two
// endpoints' keys in canonical order, the same in every grid of the volume and in its bricks.
#include <gtest/gtest.h>

#include <algorithm>
#include <map>

#include "adaptiso/extractor.hpp"
#include "adaptiso/prepare.hpp"
#include "adaptiso/synthetic.hpp"

using namespace adaptiso;

TEST(LatticeKeys, VertexKeyIsTheVoxelIndex) {
  const Dims d{5, 4, 3};
  EXPECT_EQ(lattice_key(d, {0, 0, 0}), 0u);
  EXPECT_EQ(lattice_key(d, {1, 0, 0}), 1u);
  EXPECT_EQ(lattice_key(d, {0, 1, 0}), 5u);
  EXPECT_EQ(lattice_key(d, {0, 0, 1}), 20u);
  EXPECT_EQ(lattice_key(d, {4, 3, 2}), 59u);  // the last voxel: 5·4·3 − 1
  // Large volumes: 64-bit keys, no 32-bit overflow (2^16 × 2^16 × 2^2 voxels).
  const Dims big{65536, 65536, 4};
  EXPECT_EQ(lattice_key(big, {65535, 65535, 3}), (std::uint64_t{1} << 34) - 1);
}

TEST(LatticeKeys, EdgeKeyIsCanonical) {
  EXPECT_EQ(lattice_edge(7, 3), (LatticeEdge{3, 7}));
  EXPECT_EQ(lattice_edge(3, 7), lattice_edge(7, 3));
  EXPECT_LT(lattice_edge(1, 9), lattice_edge(2, 3));  // ordered by the smaller end, then the larger
}

TEST(LatticeKeys, GridVerticesAscendInTheirKeysAndMatchTheVolume) {
  const Volume v = make_synthetic("sphere", 17, ScalarType::f32);
  PrepareOptions o;
  o.max_error = 0.05;
  o.relative = true;
  const PreparedGrid p = prepare(v, o);
  const TetGrid& g = p.grid;
  ASSERT_GT(g.vertex_count(), 8u);
  for (std::uint32_t i = 0; i < g.vertex_count(); ++i) {
    const auto& c = g.ijk[i];
    EXPECT_EQ(g.lattice_key(i), static_cast<LatticeKey>(v.index(c[0], c[1], c[2])));
    if (i > 0) {
      EXPECT_LT(g.lattice_key(i - 1), g.lattice_key(i));
    }
  }
}

TEST(LatticeKeys, TwoGridsOfOneVolumeNameTheirSharedVerticesAndEdgesAlike) {
  // A fine and a coarse grid of the same volume: the coarse one's vertices are among the fine
  // one's, under other ids and the same keys; so are the edges of their surfaces' cuts.
  const Volume v = make_synthetic("sphere", 17, ScalarType::f32);
  PrepareOptions o;
  o.max_error = 0.01;
  o.relative = true;
  const auto fine = std::make_shared<const PreparedGrid>(prepare(v, o));
  const auto coarse = std::make_shared<const PreparedGrid>(coarsen(*fine, 0.2 * (fine->grid.source.max - fine->grid.source.min)));
  ASSERT_LT(coarse->grid.vertex_count(), fine->grid.vertex_count());
  std::map<LatticeKey, std::uint32_t> fine_id;
  for (std::uint32_t i = 0; i < fine->grid.vertex_count(); ++i) fine_id[fine->grid.lattice_key(i)] = i;
  for (std::uint32_t i = 0; i < coarse->grid.vertex_count(); ++i) {
    const auto it = fine_id.find(coarse->grid.lattice_key(i));
    ASSERT_NE(it, fine_id.end());
    EXPECT_EQ(fine->grid.ijk[it->second], coarse->grid.ijk[i]);
  }
  const ValueRange r = value_range(v);
  Extractor ex(coarse);
  ex.extract(0.5 * (r.min + r.max));
  for (std::uint64_t key : ex.vertex_edges()) {
    const auto below = static_cast<std::uint32_t>(key >> 32), above = static_cast<std::uint32_t>(key & 0xffffffffu);
    const LatticeEdge e = coarse->grid.lattice_edge(below, above);
    EXPECT_LT(e.lo, e.hi);
    EXPECT_EQ(e, fine->grid.lattice_edge(fine_id.at(e.lo), fine_id.at(e.hi)));
  }
  EXPECT_GT(ex.vertex_edges().size(), 0u);
}
