// The interval tree of sweeping simplices (§2.4): the incremental sweep, the stateless query and the
// brute-force scan agree on random grids full of ties; the tree is balanced and its validator
// refuses damage.
#include <gtest/gtest.h>

#include <algorithm>
#include <iterator>
#include <random>

#include "adaptiso/interval_tree.hpp"
#include "adaptiso/synthetic.hpp"
#include "test_util.hpp"

using namespace adaptiso;

TEST(IntervalTree, IsBalancedAndHoldsEachTetInItsSmallestNode) {
  Volume v = make_synthetic("marschner-lobb", 24, ScalarType::f32);
  TetGrid g = testutil::build_grid(v, testutil::all_voxels(v));
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
