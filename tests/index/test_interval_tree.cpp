// The interval tree of sweeping simplices (§2.4): the incremental sweep, the stateless query and the
// brute-force scan agree on random grids full of ties; the tree is balanced and its validator
// refuses damage.
#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <iterator>
#include <map>
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

namespace {

// Against a brute-force reference: every node holds exactly the tetrahedra whose smallest node it
// is (down from the root by the splits until one is straddled or a leaf met), and each of its
// lists is sorted by (key, id).
void expect_each_tet_in_its_smallest_node_sorted(const IntervalTree& tree, const TetGrid& g) {
  auto range = [&](std::uint32_t t) {
    const auto& q = g.tets[t];
    double lo = g.values[q[0]], hi = lo;
    for (auto v : q) lo = std::min(lo, g.values[v]), hi = std::max(hi, g.values[v]);
    return std::pair{lo, hi};
  };
  std::vector<std::vector<std::uint32_t>> expected(tree.nodes.size());
  for (std::uint32_t t = 0; t < g.tets.size(); ++t) {
    const auto [lo, hi] = range(t);
    if (!(lo < hi)) continue;
    std::size_t i = 0;
    while (!tree.is_leaf(i) && !(lo < tree.nodes[i].split && hi > tree.nodes[i].split))
      i = hi <= tree.nodes[i].split ? 2 * i + 1 : 2 * i + 2;
    expected[i].push_back(t);
  }
  for (std::size_t i = 0; i < tree.nodes.size(); ++i) {
    const auto& n = tree.nodes[i];
    for (const auto* list : {&tree.by_min, &tree.by_max}) {
      std::vector<std::uint32_t> got(list->begin() + static_cast<std::ptrdiff_t>(n.begin),
                                     list->begin() + static_cast<std::ptrdiff_t>(n.end));
      const bool by_min = list == &tree.by_min;
      for (std::size_t k = 1; k < got.size(); ++k) {
        const auto a = range(got[k - 1]), b = range(got[k]);
        const double ka = by_min ? a.first : a.second, kb = by_min ? b.first : b.second;
        ASSERT_TRUE(ka < kb || (ka == kb && got[k - 1] < got[k])) << "node " << i << " entry " << k;
      }
      std::sort(got.begin(), got.end());
      EXPECT_EQ(got, expected[i]) << "node " << i;
    }
  }
}

// One thread builds the same lists as all.
void expect_same_tree_on_one_thread(const IntervalTree& tree, const TetGrid& g, std::uint32_t depth) {
  IntervalTree one;
  {
    tbb::global_control only(tbb::global_control::max_allowed_parallelism, 1);
    one = build_interval_tree(g, depth);
  }
  EXPECT_EQ(one.by_min, tree.by_min);
  EXPECT_EQ(one.by_max, tree.by_max);
}

}  // namespace

// Nodes are sorted by a radix sort on the key alone (equal keys keep the id order they come in).
// On a grid full of ties: each tetrahedron in its smallest node, the lists sorted by (key, id),
// and the tree the same for one thread and for all.
TEST(IntervalTree, LargeNodesFullOfTiesAreSortedAndTheSameForAnyThreadCount) {
  TetGrid g;
  std::mt19937 rng(7);
  g.values.resize(1000);
  for (auto& v : g.values) v = static_cast<double>(rng() % 16);  // 16 distinct values: ties everywhere
  g.ijk.resize(g.values.size());
  g.tets.resize(400000);
  for (auto& t : g.tets)
    for (auto& q : t) q = static_cast<std::uint32_t>(rng() % g.values.size());
  const IntervalTree tree = build_interval_tree(g, 2);
  ASSERT_GT(tree.nodes[0].end - tree.nodes[0].begin, 65536u) << "the root must take the radix sort";
  EXPECT_NO_THROW(validate_interval_tree(tree, g, "t"));
  expect_each_tet_in_its_smallest_node_sorted(tree, g);
  expect_same_tree_on_one_thread(tree, g, 2);
  // The validator still refuses a list out of order: the root's smallest and largest minimum swapped.
  IntervalTree bad = tree;
  std::swap(bad.by_min[tree.nodes[0].begin], bad.by_min[tree.nodes[0].end - 1]);
  EXPECT_THROW(validate_interval_tree(bad, g, "t"), InputError);
}

// Above 2^20 tetrahedra a node's split is the median of an evenly spaced sample: the root of 1.5 M
// random tetrahedra still splits the rest nearly in half, and the tree is valid.
TEST(IntervalTree, SampledSplitOfAHugeNodeStaysNearTheMedian) {
  TetGrid g;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> value(0, 1000);
  g.values.resize(200000);
  for (auto& v : g.values) v = value(rng);
  g.ijk.resize(g.values.size());
  g.tets.resize(1500000);
  for (auto& t : g.tets) {
    // Small value ranges, like a fine grid: four vertices close in the value order.
    const auto base = static_cast<std::uint32_t>(rng() % (g.values.size() - 8));
    for (auto& q : t) q = base + static_cast<std::uint32_t>(rng() % 8);
  }
  std::sort(g.values.begin(), g.values.end());
  const IntervalTree tree = build_interval_tree(g, 6);
  EXPECT_NO_THROW(validate_interval_tree(tree, g, "t"));
  const std::uint64_t left = tree.nodes[2].begin - tree.nodes[1].begin, total = tree.entries() - tree.nodes[0].end;
  EXPECT_LE(std::max(left, total - left), total / 2 + total / 50) << left << " of " << total;
}

// Above 2^22 tetrahedra the splits are chosen on a sample (every k-th id) and every tetrahedron
// is then walked down them: each still lands in its smallest node with its lists sorted, the
// root's split still nearly halves the rest, and one thread builds the same tree. A root of over
// 2^20 entries takes the radix sort's 16-bit digits.
TEST(IntervalTree, SplitsChosenOnASampleStillPlaceEveryTetInItsSmallestNode) {
  TetGrid g;
  std::mt19937 rng(13);
  g.values.resize(100000);
  for (auto& v : g.values) v = static_cast<double>(rng() % 4096);  // floats, with ties
  g.ijk.resize(g.values.size());
  g.tets.resize((std::size_t{1} << 22) + 123457);
  for (auto& t : g.tets) {
    // Small ranges, and one in three across the middle, so the root holds over 2^20 of them.
    const auto base = static_cast<std::uint32_t>(rng() % (g.values.size() - 16));
    for (auto& q : t) q = base + static_cast<std::uint32_t>(rng() % 16);
    const auto n = static_cast<std::uint32_t>(g.values.size());
    if (rng() % 3 == 0) t[0] = base < n / 2 ? n - 1 - rng() % 16 : rng() % 16;  // across the middle
  }
  std::sort(g.values.begin(), g.values.end());
  const IntervalTree tree = build_interval_tree(g, 8);
  EXPECT_NO_THROW(validate_interval_tree(tree, g, "t"));
  EXPECT_GT(tree.nodes[0].end - tree.nodes[0].begin, std::uint64_t{1} << 20);
  const std::uint64_t left = tree.nodes[2].begin - tree.nodes[1].begin, total = tree.entries() - tree.nodes[0].end;
  EXPECT_LE(std::max(left, total - left), total / 2 + total / 20) << left << " of " << total;
  expect_each_tet_in_its_smallest_node_sorted(tree, g);
  expect_same_tree_on_one_thread(tree, g, 8);
}

// A node of over 2^22 entries takes key arrays of over 32 MiB, populated by a nested parallel
// loop while the other worker sorts the small nodes: a worker waiting in that loop must not start
// another node's sort on the arrays in use (they were thread_local once), nor leave the largest
// nodes to one thread. The lists are those of one thread, each tetrahedron in its smallest node.
TEST(IntervalTree, NodesOfMillionsSortedBesideSmallOnesByEachWorkerGiveTheListsOfOneThread) {
  TetGrid g;
  std::mt19937 rng(19);
  g.values.resize(100000);
  for (auto& v : g.values) v = static_cast<double>(rng() % 8192);
  std::sort(g.values.begin(), g.values.end());
  g.ijk.resize(g.values.size());
  g.tets.resize((std::size_t{1} << 22) + (std::size_t{1} << 21));
  const auto n = static_cast<std::uint32_t>(g.values.size());
  for (std::size_t t = 0; t < g.tets.size(); ++t) {
    const auto base = static_cast<std::uint32_t>(rng() % (n - 16));
    for (auto& q : g.tets[t]) q = base + static_cast<std::uint32_t>(rng() % 16);
    if (t % 5 != 0) g.tets[t][0] = base < n / 2 ? n - 1 - rng() % 16 : rng() % 16;  // four in five across the middle
  }
  const IntervalTree tree = build_interval_tree(g, 8);
  ASSERT_GT(tree.nodes[0].end - tree.nodes[0].begin, (std::uint64_t{32} << 20) / 8) << "the root's keys must take a populated array";
  EXPECT_NO_THROW(validate_interval_tree(tree, g, "t"));
  expect_each_tet_in_its_smallest_node_sorted(tree, g);
  expect_same_tree_on_one_thread(tree, g, 8);
}

// Under a scratch budget, the nodes too large for it are sorted the memory-lean way (buckets by
// sampled splitters, a scatter and a permutation in place; interval_tree.hpp): the same lists as
// the fast way, on float values full of ties, on values that are not floats (pair keys) and with
// one thread. A budget of one byte sends every non-empty node, down to single entries, that way.
TEST(IntervalTree, NodesSortedWithTwoBytesAnEntryUnderAScratchBudgetGiveTheSameLists) {
  std::mt19937 rng(17);
  for (const bool floats : {true, false}) {
    TetGrid g;
    g.values.resize(50000);
    for (auto& v : g.values) v = floats ? static_cast<double>(rng() % 64) : (rng() % 64) + 1e-12 * (rng() % 1000);
    g.ijk.resize(g.values.size());
    g.tets.resize(700000);
    for (auto& t : g.tets)
      for (auto& q : t) q = static_cast<std::uint32_t>(rng() % g.values.size());
    const IntervalTree fast = build_interval_tree(g, 3);
    for (const std::size_t budget : {std::size_t{1}, std::size_t{4} << 20}) {
      const IntervalTree lean = build_interval_tree(g, 3, budget);
      EXPECT_EQ(lean.by_min, fast.by_min) << "floats " << floats << ", budget " << budget;
      EXPECT_EQ(lean.by_max, fast.by_max) << "floats " << floats << ", budget " << budget;
    }
    expect_each_tet_in_its_smallest_node_sorted(fast, g);
    IntervalTree one;
    {
      tbb::global_control only(tbb::global_control::max_allowed_parallelism, 1);
      one = build_interval_tree(g, 3, 1);
    }
    EXPECT_EQ(one.by_min, fast.by_min);
    EXPECT_EQ(one.by_max, fast.by_max);
  }
}

// The validator checks the lists in even chunks that cut through nodes (the root alone can hold a
// tenth of the entries), so the order of two neighbours on either side of a cut must still be
// checked. TBB cuts [0, E) first at E/2 (then E/4, 3E/4, …): two neighbours swapped there, in one
// node and with different keys, are out of order only against each other.
TEST(IntervalTree, ValidatorRefusesNeighboursOutOfOrderAcrossItsChunks) {
  TetGrid g;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> value(0, 1000);
  g.tets.resize(600000);
  g.values.resize(4 * g.tets.size());  // vertices of their own, so neighbours' keys differ
  for (auto& v : g.values) v = value(rng);
  g.ijk.resize(g.values.size());
  for (std::uint32_t t = 0; t < g.tets.size(); ++t) g.tets[t] = {4 * t, 4 * t + 1, 4 * t + 2, 4 * t + 3};
  const IntervalTree tree = build_interval_tree(g, 1);  // the root and two leaves: large nodes
  ASSERT_NO_THROW(validate_interval_tree(tree, g, "t"));
  auto key = [&](std::uint32_t t, bool by_min) {
    const auto& q = g.tets[t];
    double lo = g.values[q[0]], hi = lo;
    for (auto v : q) lo = std::min(lo, g.values[v]), hi = std::max(hi, g.values[v]);
    return by_min ? lo : hi;
  };
  const std::uint64_t E = tree.entries();
  int tried = 0;
  for (std::uint64_t k : {E / 2, E / 4, E / 2 + E / 4}) {
    for (bool by_min : {true, false}) {
      IntervalTree bad = tree;
      auto& list = by_min ? bad.by_min : bad.by_max;
      const bool one_node = std::none_of(tree.nodes.begin(), tree.nodes.end(), [&](const auto& n) { return n.begin == k; });
      if (!one_node || key(list[k - 1], by_min) == key(list[k], by_min)) continue;
      std::swap(list[k - 1], list[k]);
      EXPECT_THROW(validate_interval_tree(bad, g, "t"), InputError)
          << "entries " << k - 1 << ", " << k << (by_min ? " by minimum" : " by maximum");
      ++tried;
    }
  }
  EXPECT_GE(tried, 4);
}

// A grid file streamed as it is made (prepare_to_file) writes the index's depth and entries before
// the index exists: interval_tree_shape must give what the build will, where the depth is reduced
// (few entries for the leaves asked for: counted exactly, or estimated from every k-th
// tetrahedron above 2^23 of them), where every tetrahedron is constant and where there are none.
TEST(IntervalTree, ShapeKnownBeforeTheBuildIsTheBuiltTreesDepthAndEntries) {
  std::mt19937 rng(29);
  auto random_grid = [&](std::size_t tets, std::size_t vertices, int nonconstant_one_in) {
    TetGrid g;
    g.values.resize(vertices);
    for (auto& v : g.values) v = static_cast<double>(rng() % 50);
    g.ijk.resize(vertices);
    g.tets.resize(tets);
    for (auto& t : g.tets) {
      if (rng() % nonconstant_one_in == 0)
        for (auto& q : t) q = static_cast<std::uint32_t>(rng() % vertices);
      else
        t = {0, 0, 0, 0};
    }
    return g;
  };
  struct Case {
    std::size_t tets, vertices;
    int one_in;
    std::uint32_t depth;
  };
  for (const Case& c : {Case{0, 1, 1, 12}, Case{1, 4, 1, 12}, Case{100, 4, 1000000, 5}, Case{5000, 300, 1, 0}, Case{5000, 300, 1, 12},
                        Case{5000, 300, 3, 30}, Case{200000, 1000, 7, 20}}) {
    const TetGrid g = random_grid(c.tets, c.vertices, c.one_in);
    const IntervalTree tree = build_interval_tree(g, c.depth);
    const IntervalTreeShape shape = interval_tree_shape(g, c.depth);
    EXPECT_EQ(shape.depth, tree.depth) << c.tets << " tetrahedra, depth " << c.depth;
    EXPECT_EQ(shape.entries, tree.entries()) << c.tets << " tetrahedra, depth " << c.depth;
    EXPECT_EQ(shape.nodes(), tree.nodes.size());
  }
  // Sampled: 2^23 tetrahedra (every third one sampled), one in 4,000 non-constant, so the depth
  // asked for (16) comes down to what the sample estimates.
  TetGrid big = random_grid(std::size_t{1} << 23, 64, 4000);
  const IntervalTree tree = build_interval_tree(big, 16);
  const IntervalTreeShape shape = interval_tree_shape(big, 16);
  EXPECT_LT(tree.depth, 16u);
  EXPECT_EQ(shape.depth, tree.depth);
  EXPECT_EQ(shape.entries, tree.entries());
}
